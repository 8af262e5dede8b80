"""Simulated rooms at the level of bits: what the sensor reports at each timer value.

A :class:`Room` gives, for every timer value z, the probability that the window's bit is
1, plus the ground truth (is a responsive partner there). Rooms are specified on the
command line as ``NAME`` or ``NAME:key=value,...`` with a name of the registry
:data:`~infomax_contingency.sim.rooms.ROOMS`:

* ``prior`` — S, K1, K2, K3 drawn from the model's priors (``pi=`` overrides P(S=1)).
* ``responsive`` — a partner answers: ``k1`` (robot hears itself, default 0.9),
  ``k2`` (agent period, default 0.8), ``k3`` (background, default 0.1).
* ``silent`` — nobody answers, a quiet room: ``k1`` 0.9, ``k3`` 0.02 (``k2 = k3``).
* ``noisy`` — nobody answers, a loud room: ``k1`` 0.9, ``k3`` 0.5 (``k2 = k3``).
* ``baby9`` — MODEL.md section 5: active at every agent-period step (``reply=all``) or
  only at timer value ``reply=N``; silent otherwise; self-feedback bits 0.
* ``quiet``, ``office``, ``poster-session`` (each also ``+partner``) — the named
  backgrounds of the efficiency experiment (``k1``, ``k3`` and with a partner ``k2``
  may be overridden).

The registry's ``audio`` rooms (``tv-on``, the ``+arriving`` and ``+leaving`` rooms) have
no bit-level form; :func:`make_room` refuses them, naming where they are used.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core.model import AGENT, BACKGROUND, SELF, ModelParams, period_of
from infomax_contingency.sim.rooms import (
    BIT_ROOM_NAMES,
    NAMED_BACKGROUNDS,
    ROOM_NAMES,
    RoomKind,
    room_kind,
)

__all__ = ["BIT_ROOM_NAMES", "ROOM_NAMES", "Room", "make_room", "named_room", "room_from_rates"]


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
        if key.strip() in options:
            raise ValueError(f"room {spec!r}: {key.strip()} is given twice")
        options[key.strip()] = value.strip()
    return name.strip(), options


def _float_option(options: dict[str, str], key: str, default: float, spec: str) -> float:
    """The probability option ``key`` of a specification, or ``default`` when it is not given."""
    text = options.get(key)
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"room {spec!r}: {key} must be a number, got {text!r}") from None
    if not 0.0 <= value <= 1.0:  # NaN too
        raise ValueError(f"room {spec!r}: {key} must be a probability in [0, 1], got {text}")
    return value


def _prior_room(params: ModelParams, spec: str, pi: float, rng: np.random.Generator) -> Room:
    """S with P(S=1) = pi, then K1, K3 and (with a partner) K2 from the model's priors."""
    partner = bool(rng.random() < pi)
    k1 = rng.beta(params.b11, params.b12)
    k3 = rng.beta(params.b31, params.b32)
    k2 = rng.beta(params.b21, params.b22) if partner else k3
    return room_from_rates(params, spec, partner, k1, k2, k3)


def _baby9_room(params: ModelParams, spec: str, reply: str) -> Room:
    """Active at every agent-period timer value (``all``) or only at ``reply``; else silent."""
    if reply == "all":
        answered = range(params.ta1, params.ta2 + 1)
    elif reply.isdigit() and params.ta1 <= int(reply) <= params.ta2:
        answered = range(int(reply), int(reply) + 1)
    else:
        raise ValueError(
            f"room {spec!r}: reply must be 'all' or a timer value in"
            f" {params.ta1}..{params.ta2} (the agent period)"
        )
    rates = tuple(1.0 if z in answered else 0.0 for z in range(params.n_timer_values))
    return Room(spec, True, rates)


def _rates_room(params: ModelParams, kind: RoomKind, spec: str, options: dict[str, str]) -> Room:
    """A room of fixed rates: the kind's defaults, overridden by the options k1, k2, k3."""
    if kind.rates is None:
        raise ValueError(f"room {kind.name!r} is not a room of fixed rates")
    k1 = _float_option(options, "k1", kind.rates.k1, spec)
    k3 = _float_option(options, "k3", kind.rates.k3, spec)
    if kind.rates.k2 is None:  # nobody answers: the agent period is background
        return room_from_rates(params, spec, bool(kind.partner_present), k1, k3, k3)
    k2 = _float_option(options, "k2", kind.rates.k2, spec)
    return room_from_rates(params, spec, bool(kind.partner_present), k1, k2, k3)


def make_room(spec: str, params: ModelParams, rng: np.random.Generator) -> Room:
    """Parse a room specification (see the module docstring); draws from ``rng`` for prior."""
    name, options = _parse_options(spec)
    kind = room_kind(name)
    if kind.family == "audio":
        raise ValueError(
            f"room {name!r} exists only as sound (fake_audio_node, experiment rooms, room-wav);"
            f" bit-level rooms: {', '.join(BIT_ROOM_NAMES)}"
        )
    unknown = sorted(set(options) - set(kind.options))
    if unknown:
        raise ValueError(f"room {spec!r}: unknown option(s) {unknown}")
    if kind.family == "prior":
        return _prior_room(params, spec, _float_option(options, "pi", params.pi, spec), rng)
    if kind.family == "baby9":
        return _baby9_room(params, spec, options.get("reply", "all"))
    return _rates_room(params, kind, spec, options)


def named_room(params: ModelParams, name: str) -> Room:
    """``quiet``, ``office``, ``poster-session``, each optionally ``+partner`` (no options)."""
    base, _, suffix = name.partition("+")
    if base not in NAMED_BACKGROUNDS or suffix not in ("", "partner"):
        choices = ", ".join(f"{n}[+partner]" for n in NAMED_BACKGROUNDS)
        raise ValueError(f"unknown named room {name!r}; rooms: {choices}")
    return _rates_room(params, room_kind(name), name, {})
