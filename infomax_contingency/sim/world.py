"""Simulated rooms at the level of bits: what the sensor reports at each timer value.

A :class:`Room` gives, for every timer value z, the probability that the window's bit is
1, plus the ground truth (is a responsive partner there). Rooms are specified on the
command line as ``NAME`` or ``NAME:key=value,...``:

* ``prior`` — S, K1, K2, K3 drawn from the model's priors (``pi=`` overrides P(S=1)).
* ``responsive`` — a partner answers: ``k1`` (robot hears itself, default 0.9),
  ``k2`` (agent period, default 0.8), ``k3`` (background, default 0.1).
* ``silent`` — nobody answers, a quiet room: ``k1`` 0.9, ``k3`` 0.02 (``k2 = k3``).
* ``noisy`` — nobody answers, a loud room: ``k1`` 0.9, ``k3`` 0.5 (``k2 = k3``).
* ``baby9`` — MODEL.md section 5: active at every agent-period step (``reply=all``) or
  only at timer value ``reply=N``; silent otherwise; self-feedback bits 0.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core.model import AGENT, BACKGROUND, SELF, ModelParams, period_of

ROOM_NAMES = ("prior", "responsive", "silent", "noisy", "baby9")


@dataclasses.dataclass(frozen=True)
class Room:
    """Activation probability per timer value, and the ground truth.

    Attributes:
        name: how the room was specified.
        partner_present: the true S.
        rates: P(y = 1) for each timer value ``0 .. ta2 + 1``.
    """

    name: str
    partner_present: bool
    rates: tuple[float, ...]

    def draw_bit(self, z: int, rng: np.random.Generator) -> int:
        """One window's bit at timer value z."""
        return int(rng.random() < self.rates[z])


def room_from_rates(
    params: ModelParams, name: str, partner_present: bool, k1: float, k2: float, k3: float
) -> Room:
    """A room whose bits follow the model: rate k1, k2, k3 in the self, agent, background period."""
    for label, value in (("k1", k1), ("k2", k2), ("k3", k3)):
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"room {name!r}: {label} must be a probability in [0, 1], got {value}")
    by_period = {SELF: k1, AGENT: k2, BACKGROUND: k3}
    periods = period_of(params, np.arange(params.n_timer_values))
    return Room(name, partner_present, tuple(float(by_period[int(p)]) for p in periods))


def _parse_options(spec: str) -> tuple[str, dict[str, str]]:
    name, _, rest = spec.partition(":")
    options = {}
    for item in filter(None, rest.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"room option {item!r} in {spec!r} must look like key=value")
        options[key.strip()] = value.strip()
    return name.strip(), options


def _float_option(options: dict[str, str], key: str, default: float, spec: str) -> float:
    try:
        return float(options.pop(key, default))
    except ValueError:
        raise ValueError(f"room {spec!r}: {key} must be a number, got {options[key]!r}") from None


def make_room(spec: str, params: ModelParams, rng: np.random.Generator) -> Room:
    """Parse a room specification (see the module docstring); draws from ``rng`` for prior."""
    name, options = _parse_options(spec)
    if name == "prior":
        pi = _float_option(options, "pi", params.pi, spec)
        partner = bool(rng.random() < pi)
        k1 = rng.beta(params.b11, params.b12)
        k3 = rng.beta(params.b31, params.b32)
        k2 = rng.beta(params.b21, params.b22) if partner else k3
        room = room_from_rates(params, spec, partner, k1, k2, k3)
    elif name == "responsive":
        room = room_from_rates(
            params,
            spec,
            True,
            _float_option(options, "k1", 0.9, spec),
            _float_option(options, "k2", 0.8, spec),
            _float_option(options, "k3", 0.1, spec),
        )
    elif name in ("silent", "noisy"):
        k3 = _float_option(options, "k3", 0.02 if name == "silent" else 0.5, spec)
        k1 = _float_option(options, "k1", 0.9, spec)
        room = room_from_rates(params, spec, False, k1, k3, k3)
    elif name == "baby9":
        reply = options.pop("reply", "all")
        if reply == "all":
            rates = [
                1.0 if params.ta1 <= z <= params.ta2 else 0.0 for z in range(params.n_timer_values)
            ]
        else:
            if not reply.isdigit() or not params.ta1 <= int(reply) <= params.ta2:
                raise ValueError(
                    f"room {spec!r}: reply must be 'all' or a timer value in"
                    f" {params.ta1}..{params.ta2} (the agent period)"
                )
            rates = [1.0 if z == int(reply) else 0.0 for z in range(params.n_timer_values)]
        room = Room(spec, True, tuple(rates))
    else:
        raise ValueError(f"unknown room {name!r}; rooms: {', '.join(ROOM_NAMES)}")
    if options:
        raise ValueError(f"room {spec!r}: unknown option(s) {sorted(options)}")
    return room
