"""The one registry of room names: what each named room is, at the bit and the audio level.

Every name a command, experiment or node accepts for a simulated room is a key of
:data:`ROOMS`. Each :class:`RoomKind` states

* its bit-level behaviour (used by :func:`infomax_contingency.sim.world.make_room`):
  drawn from the model's priors (``prior``), the baby-9 scenario of MODEL.md section 5
  (``baby9``), or fixed activation rates ``k1`` (self-feedback period), ``k2`` (agent
  period) and ``k3`` (background) — the probability that a window of that period is
  active;
* and, where it has one, its audio-level preset: the fields of
  :class:`~infomax_contingency.sim.fake_room.FakeRoomConfig` it sets
  (:data:`~infomax_contingency.sim.fake_room.PRESETS` is made from these).

The rooms ``quiet``, ``office`` and ``poster-session`` (each also ``+partner``) are the
named backgrounds of the efficiency experiment: background activity
:data:`NAMED_BACKGROUNDS`, the robot hears itself with :data:`SELF_HEARING`, and a present
partner makes an agent-period window active with :data:`PARTNER_REPLY` on top of the
background.

This module holds data only (no I/O, no randomness).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Literal

RoomFamily = Literal["prior", "baby9", "rates"]
"""How a room's bits are made: drawn from the priors, the baby-9 scenario, fixed rates."""


@dataclasses.dataclass(frozen=True)
class BitRates:
    """Default activation rates of a rate room, probabilities per window.

    Attributes:
        k1: self-feedback period (the robot hears itself).
        k2: agent period; ``None`` when nobody answers (then ``k2 = k3``, whatever k3 is).
        k3: background period.
    """

    k1: float
    k2: float | None
    k3: float


@dataclasses.dataclass(frozen=True)
class RoomKind:
    """One named room.

    Attributes:
        name: the name used on command lines and in parameters.
        summary: one line saying what the room is.
        family: how its bits are made (see :data:`RoomFamily`).
        partner_present: the true S; ``None`` when drawn (``prior``).
        rates: default rates of a ``rates`` room (options ``k1``, ``k3`` and, with a
            partner, ``k2`` override them); ``None`` for the other families.
        audio: the :class:`~infomax_contingency.sim.fake_room.FakeRoomConfig` fields of
            its audio-level preset; ``None``: the room exists at the bit level only.
    """

    name: str
    summary: str
    family: RoomFamily
    partner_present: bool | None
    rates: BitRates | None = None
    audio: Mapping[str, Any] | None = None

    @property
    def options(self) -> tuple[str, ...]:
        """The ``key=value`` options its specification accepts."""
        if self.family == "prior":
            return ("pi",)
        if self.family == "baby9":
            return ("reply",)
        return ("k1", "k2", "k3") if self.partner_present else ("k1", "k3")


NAMED_BACKGROUNDS = {"quiet": 0.05, "office": 0.2, "poster-session": 0.5}
"""Background activity of the named rooms: P(window active) outside the agent period."""

PARTNER_REPLY = 0.6
"""P(a present partner makes an agent-period window active): the window is active if the
partner replies or the background is active, ``k2 = 1 - (1 - k3)(1 - PARTNER_REPLY)``."""

SELF_HEARING = 0.9
"""P(the robot hears itself in a self-feedback window), ``k1``."""


def _named_background_rooms() -> list[RoomKind]:
    """``quiet``, ``office``, ``poster-session`` and their ``+partner`` variants."""
    kinds = []
    for name, k3 in NAMED_BACKGROUNDS.items():
        kinds.append(
            RoomKind(
                name,
                f"nobody answers; background activity {k3:g}",
                "rates",
                False,
                BitRates(SELF_HEARING, None, k3),
            )
        )
        kinds.append(
            RoomKind(
                f"{name}+partner",
                f"a partner answers with {PARTNER_REPLY:g} over background activity {k3:g}",
                "rates",
                True,
                BitRates(SELF_HEARING, 1.0 - (1.0 - k3) * (1.0 - PARTNER_REPLY), k3),
            )
        )
    return kinds


def _registry(kinds: list[RoomKind]) -> Mapping[str, RoomKind]:
    return MappingProxyType({kind.name: kind for kind in kinds})


ROOMS: Mapping[str, RoomKind] = _registry(
    [
        RoomKind(
            "prior", "S, K1, K2, K3 drawn from the model's priors (pi= sets P(S=1))", "prior", None
        ),
        RoomKind(
            "responsive",
            "a partner answers, in a fairly quiet room",
            "rates",
            True,
            BitRates(0.9, 0.8, 0.1),
            MappingProxyType(
                {"partner_arrive_s": 0.0, "partner_leave_s": -1.0, "event_rate_hz": 0.1}
            ),
        ),
        RoomKind(
            "silent",
            "nobody answers, a quiet room",
            "rates",
            False,
            BitRates(0.9, None, 0.02),
            MappingProxyType({"partner_arrive_s": -1.0, "event_rate_hz": 0.02}),
        ),
        RoomKind(
            "noisy",
            "nobody answers, a loud room (about half the windows hold a sound)",
            "rates",
            False,
            BitRates(0.9, None, 0.5),
            MappingProxyType({"partner_arrive_s": -1.0, "event_rate_hz": 1.0}),
        ),
        RoomKind(
            "baby9",
            "MODEL.md section 5: active at every agent-period step (reply=all) or only at"
            " timer value reply=N; silent otherwise",
            "baby9",
            True,
        ),
        *_named_background_rooms(),
    ]
)
"""Every named room, in the order commands list them."""

ROOM_NAMES: tuple[str, ...] = tuple(ROOMS)
"""The names of :data:`ROOMS`."""

AUDIO_ROOM_NAMES: tuple[str, ...] = tuple(name for name, kind in ROOMS.items() if kind.audio)
"""The rooms that have an audio-level preset."""


def room_kind(name: str) -> RoomKind:
    """The registry entry of a room name; ``ValueError`` naming every room if unknown."""
    try:
        return ROOMS[name]
    except KeyError:
        raise ValueError(f"unknown room {name!r}; rooms: {', '.join(ROOM_NAMES)}") from None
