"""The one registry of room names: what each named room is, at the bit and the audio level.

Every name a command, experiment or node accepts for a simulated room is a key of
:data:`ROOMS`. Each :class:`RoomKind` states

* its bit-level behaviour (used by :func:`infomax_contingency.sim.world.make_room`):
  drawn from the model's priors (``prior``), the baby-9 scenario of MODEL.md section 5
  (``baby9``), or fixed activation rates ``k1`` (self-feedback period), ``k2`` (agent
  period) and ``k3`` (background) — the probability that a window of that period is
  active;
* and, where it has one, its audio-level preset: the fields of
  :class:`~infomax_contingency.sim.room_config.FakeRoomConfig` it sets
  (:data:`~infomax_contingency.sim.room_config.PRESETS` is made from these).

The rooms ``quiet``, ``office`` and ``poster-session`` (each also ``+partner``) are the
named backgrounds of the efficiency experiment: background activity
:data:`NAMED_BACKGROUNDS`, the robot hears itself with :data:`SELF_HEARING`, and a present
partner makes an agent-period window active with :data:`PARTNER_REPLY` on top of the
background.

The same names, and ``tv-on``, are also rooms that sound like rooms
(:data:`ROOM_SOUNDS`, the sources of :mod:`infomax_contingency.sim.fake_room`), each
with the partner absent (``NAME``), present (``NAME+partner``), arriving
(``NAME+arriving``) or leaving (``NAME+leaving``) :data:`ROOM_CHANGE_S` seconds into the
room; ``tv-on`` and the arriving and leaving rooms exist at the audio level only (family
``audio``). Their levels, dB FS (RMS over each sound's duration; floor, babble and TV
over all time, pauses included):

============== ====== ======== ==== ====== ===== ========= ===== =========
room           floor  babble   TV   knocks doors footsteps chirp echo/RT60
============== ====== ======== ==== ====== ===== ========= ===== =========
quiet          -60 p  --       --   -35    --    --        -20   -38/0.3 s
office         -50 h  -45 x 2  --   -32    -22   -40       -20   -34/0.5 s
poster-session -45 p  -30 x 12 --   -30    --    -36       -20   -32/0.6 s
tv-on          -55 p  --       -33  -32    --    -40       -20   -36/0.4 s
============== ====== ======== ==== ====== ===== ========= ===== =========

(p: pink floor, h: hvac floor; babble: long-term level x talkers.) Eight more rooms
(:data:`_NEWER_ROOMS`: open-office, cafe, living-room, tv-switched-on, crowd-grows and the
held-out kitchen, street, home-office) are built from sources unlike these: espeak-ng
speech, music, a mains hum, traffic, typing; their levels are in docs/RESULTS.md
section 7. The partner's replies
are speech-like (``reply_voice`` ``speech``) at -26 dB (-24 dB in the poster session,
where people speak up), answering 90 % of vocalizations 1.0 .. 1.4 s after them, for
0.6 .. 1.0 s: inside the agent period of the ``robot`` parameters; in the newer rooms they
are espeak-ng sentences (``reply_voice`` ``tts``).

Four rooms held out later (:data:`HELD_OUT_LATER`, also in :data:`_NEWER_ROOMS`) are
each built around a source no other room has
(:mod:`~infomax_contingency.sim.household_streams`); levels as above (children, toys,
barks, spin and vacuum: RMS over each sound; the washer's wash over all time):

================ ====== =========================================== ======= =========
room             floor  sources                                     partner echo/RT60
================ ====== =========================================== ======= =========
playroom         -55 p  3 children talking and shouting in bursts   -24     -35/0.5 s
                        -33 (+-4 a burst); toys -38, 1 per 10 s
dog-home         -58 p  a dog: clusters of 1-5 barks -30, one per   -26     -36/0.4 s
                        12-20 s; fridge hum -48
laundry          -52 h  washing machine -40 (drum at 0.8-1.2 Hz);   -26     -34/0.6 s
                        a spin of 6-12 s every 20-30 s -34 over it
                        (+7-8 dB over the wash at full speed)
vacuum-next-door -54 p  a vacuum next door -36, on 5-25 s, off      -26     -36/0.4 s
                        5-20 s; a radio talker -44 (2 kHz)
================ ====== =========================================== ======= =========

This module holds data only (no I/O, no randomness).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Literal

RoomFamily = Literal["prior", "baby9", "rates", "audio"]
"""How a room's bits are made: drawn from the priors, the baby-9 scenario, fixed rates;
``audio``: a room that exists at the audio level only (its bits come from its sound)."""


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
        partner_present: the true S; ``None`` when drawn (``prior``) or when it changes
            during the run (a partner arriving or leaving: see the audio preset's
            ``partner_arrive_s`` and ``partner_leave_s``).
        rates: default rates of a ``rates`` room (options ``k1``, ``k3`` and, with a
            partner, ``k2`` override them); ``None`` for the other families.
        audio: the :class:`~infomax_contingency.sim.room_config.FakeRoomConfig` fields of
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
        if self.family == "audio":
            return ()
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


ROOM_CHANGE_S = 20.0
"""Room time at which the partner of an ``+arriving`` room arrives, or of a ``+leaving``
room leaves, seconds."""

PARTNER_STATES = ("", "+partner", "+arriving", "+leaving")
"""Suffixes of an audio room's name: partner absent, present, arriving, leaving."""

_SPEECH_REPLY = {"reply_voice": "speech", "reply_level_db": -26.0}
_NOTHING_ELSE = {"event_rate_hz": 0.0, "door_rate_hz": 0.0, "footsteps_rate_hz": 0.0}

_TTS_REPLY = {"reply_voice": "tts", "reply_level_db": -26.0}

_NEWER_ROOMS: dict[str, dict[str, Any]] = {
    # -- rooms the detector's settings were chosen on (with the four above)
    "open-office": {
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "hvac", "noise_floor_db": -52.0,
        "hum_on": True, "hum_level_db": -47.0,
        "typing_rate_hz": 0.08, "typing_level_db": -36.0,
        "babble_talkers": 3, "babble_voice": "tts", "babble_level_db": -42.0,
        "babble_cutoff_hz": 1500.0,
        "reverb_rt60_s": 0.5, "reverb_level_db": -34.0,
    },
    "cafe": {
        **_NOTHING_ELSE, **_TTS_REPLY, "reply_level_db": -24.0,
        "floor_spectrum": "pink", "noise_floor_db": -48.0,
        "babble_talkers": 8, "babble_voice": "tts", "babble_level_db": -33.0,
        "babble_cutoff_hz": 2000.0,
        "music_on": True, "music_level_db": -38.0,
        "event_rate_hz": 0.15, "event_level_db": -30.0,
        "reverb_rt60_s": 0.6, "reverb_level_db": -32.0,
    },
    "living-room": {
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "pink", "noise_floor_db": -56.0,
        "tv_on": True, "tv_voice": "tts", "tv_level_db": -32.0,
        "footsteps_rate_hz": 0.03, "footsteps_level_db": -40.0,
        "reverb_rt60_s": 0.4, "reverb_level_db": -36.0,
    },
    "tv-switched-on": {  # changes: the TV comes on 30 s into the room
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "pink", "noise_floor_db": -56.0,
        "tv_on": True, "tv_voice": "tts", "tv_level_db": -32.0, "tv_start_s": 30.0,
        "footsteps_rate_hz": 0.03, "footsteps_level_db": -40.0,
        "reverb_rt60_s": 0.4, "reverb_level_db": -36.0,
    },
    "crowd-grows": {  # changes: 12 talkers join one every 2 s (all there from 22 s)
        **_NOTHING_ELSE, **_TTS_REPLY, "reply_level_db": -24.0,
        "floor_spectrum": "pink", "noise_floor_db": -50.0,
        "babble_talkers": 12, "babble_voice": "tts", "babble_level_db": -31.0,
        "babble_cutoff_hz": 2000.0, "babble_join_s": 2.0,
        "reverb_rt60_s": 0.6, "reverb_level_db": -32.0,
    },
    # -- held out: nothing was chosen on these rooms (HELD_OUT_BACKGROUNDS)
    "kitchen": {
        **_NOTHING_ELSE, **_TTS_REPLY, "reply_level_db": -25.0,
        "floor_spectrum": "white", "noise_floor_db": -58.0,
        "music_on": True, "music_level_db": -36.0,
        "hum_on": True, "hum_level_db": -45.0,
        "event_rate_hz": 0.1, "event_level_db": -28.0,
        "reverb_rt60_s": 0.5, "reverb_level_db": -33.0,
    },
    "street": {
        **_NOTHING_ELSE, **_TTS_REPLY, "reply_level_db": -24.0,
        "floor_spectrum": "hvac", "noise_floor_db": -47.0,
        "traffic_rate_hz": 0.12, "traffic_level_db": -31.0,
        "footsteps_rate_hz": 0.08, "footsteps_level_db": -38.0,
        "babble_talkers": 2, "babble_voice": "tts", "babble_level_db": -44.0,
        "babble_cutoff_hz": 2500.0,
        "reverb_rt60_s": 0.2, "reverb_level_db": -42.0,
    },
    "home-office": {
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "pink", "noise_floor_db": -57.0,
        "typing_rate_hz": 0.1, "typing_level_db": -34.0,
        "hum_on": True, "hum_level_db": -50.0,
        "traffic_rate_hz": 0.05, "traffic_level_db": -42.0,
        "babble_talkers": 1, "babble_voice": "tts", "babble_level_db": -40.0,
        "babble_cutoff_hz": 3000.0,
        "reverb_rt60_s": 0.4, "reverb_level_db": -36.0,
    },
    # -- held out later (HELD_OUT_LATER): built after every setting was chosen
    "playroom": {  # three children talking and shouting, toys; people speak up
        **_NOTHING_ELSE, **_TTS_REPLY, "reply_level_db": -24.0,
        "floor_spectrum": "pink", "noise_floor_db": -55.0,
        "children_talkers": 3, "children_level_db": -33.0,
        "toy_rate_hz": 0.1, "toy_level_db": -38.0,
        "reverb_rt60_s": 0.5, "reverb_level_db": -35.0,
    },
    "dog-home": {  # a dog barking now and then, a fridge
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "pink", "noise_floor_db": -58.0,
        "bark_rate_hz": 0.0625, "bark_level_db": -30.0,
        "hum_on": True, "hum_level_db": -48.0,
        "reverb_rt60_s": 0.4, "reverb_level_db": -36.0,
    },
    "laundry": {  # a washing machine washing, spinning every 20-30 s
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "hvac", "noise_floor_db": -52.0,
        "washer_on": True, "washer_level_db": -40.0, "washer_spin_level_db": -34.0,
        "reverb_rt60_s": 0.6, "reverb_level_db": -34.0,
    },
    "vacuum-next-door": {  # someone vacuuming next door, a radio talk show far off
        **_NOTHING_ELSE, **_TTS_REPLY,
        "floor_spectrum": "pink", "noise_floor_db": -54.0,
        "vacuum_on": True, "vacuum_level_db": -36.0,
        "babble_talkers": 1, "babble_voice": "tts", "babble_level_db": -44.0,
        "babble_cutoff_hz": 2000.0,
        "reverb_rt60_s": 0.4, "reverb_level_db": -36.0,
    },
}
"""The rooms built from sources unlike the first four's: sentences spoken by espeak-ng
(distant talkers, a TV, the partner), music, a mains hum, traffic passing, typing; two
that change during the run (``tv-switched-on``, ``crowd-grows``) and three held out
(:data:`HELD_OUT_BACKGROUNDS`); then four held out later, from sources unlike all of
these (:data:`HELD_OUT_LATER`). Levels: docs/RESULTS.md section 7 and the table of
the module docstring."""  # fmt: skip

HELD_OUT_BACKGROUNDS = ("kitchen", "street", "home-office")
"""Rooms no setting of the self-calibrating detector was chosen on (reported apart)."""

HELD_OUT_LATER = ("playroom", "dog-home", "laundry", "vacuum-next-door")
"""A second held-out set, built after the detector's settings were chosen, each around a
source no other room has (children, toys, a dog, a washing machine, a vacuum cleaner):
no detector setting was chosen on them, and they were not run through the detector while
they were built (only their levels were measured)."""

BACKGROUND_CHANGES_S: Mapping[str, float] = MappingProxyType(
    {"tv-switched-on": 30.0, "crowd-grows": 22.0}
)
"""Rooms whose background changes during the run: when the change is complete, room
seconds (the TV switched on; the last of the crowd's talkers joins)."""


ROOM_SOUNDS: Mapping[str, Mapping[str, Any]] = MappingProxyType(
    {
        "quiet": MappingProxyType(
            {
                **_NOTHING_ELSE,
                **_SPEECH_REPLY,
                "floor_spectrum": "pink",
                "noise_floor_db": -60.0,
                "event_rate_hz": 0.02,
                "event_level_db": -35.0,
                "reverb_rt60_s": 0.3,
                "reverb_level_db": -38.0,
            }
        ),
        "office": MappingProxyType(
            {
                **_NOTHING_ELSE,
                **_SPEECH_REPLY,
                "floor_spectrum": "hvac",
                "noise_floor_db": -50.0,
                "babble_talkers": 2,
                "babble_level_db": -45.0,
                "babble_cutoff_hz": 1000.0,
                "event_rate_hz": 0.05,
                "event_level_db": -32.0,
                "door_rate_hz": 0.01,
                "door_level_db": -22.0,
                "footsteps_rate_hz": 0.03,
                "footsteps_level_db": -40.0,
                "reverb_rt60_s": 0.5,
                "reverb_level_db": -34.0,
            }
        ),
        "poster-session": MappingProxyType(
            {
                **_NOTHING_ELSE,
                **_SPEECH_REPLY,
                "reply_level_db": -24.0,
                "floor_spectrum": "pink",
                "noise_floor_db": -45.0,
                "babble_talkers": 12,
                "babble_level_db": -30.0,
                "babble_cutoff_hz": 1500.0,
                "event_rate_hz": 0.1,
                "event_level_db": -30.0,
                "footsteps_rate_hz": 0.1,
                "footsteps_level_db": -36.0,
                "reverb_rt60_s": 0.6,
                "reverb_level_db": -32.0,
            }
        ),
        "tv-on": MappingProxyType(
            {
                **_NOTHING_ELSE,
                **_SPEECH_REPLY,
                "floor_spectrum": "pink",
                "noise_floor_db": -55.0,
                "tv_on": True,
                "tv_level_db": -33.0,
                "event_rate_hz": 0.03,
                "event_level_db": -32.0,
                "footsteps_rate_hz": 0.02,
                "footsteps_level_db": -40.0,
                "reverb_rt60_s": 0.4,
                "reverb_level_db": -36.0,
            }
        ),
        **{name: MappingProxyType(fields) for name, fields in _NEWER_ROOMS.items()},
    }
)
"""The sound of each audio room's background (fields of
:class:`~infomax_contingency.sim.room_config.FakeRoomConfig`; levels in the module
docstring's table). The partner's presence is added per :data:`PARTNER_STATES`."""

_PARTNER_TIMES = {
    "": {"partner_arrive_s": -1.0, "partner_leave_s": -1.0},
    "+partner": {"partner_arrive_s": 0.0, "partner_leave_s": -1.0},
    "+arriving": {"partner_arrive_s": ROOM_CHANGE_S, "partner_leave_s": -1.0},
    "+leaving": {"partner_arrive_s": 0.0, "partner_leave_s": ROOM_CHANGE_S},
}


def audio_preset(background: str, state: str) -> Mapping[str, Any]:
    """The audio preset of ``background`` (a key of :data:`ROOM_SOUNDS`) in a partner state."""
    return MappingProxyType({**ROOM_SOUNDS[background], **_PARTNER_TIMES[state]})


def _with_sound(kind: RoomKind) -> RoomKind:
    """A named-background room with its audio preset."""
    background, plus, state = kind.name.partition("+")
    return dataclasses.replace(kind, audio=audio_preset(background, plus + state))


def _audio_only_rooms() -> list[RoomKind]:
    """``tv-on`` (and ``+partner``) and every background's ``+arriving`` / ``+leaving``."""
    what = {
        "": "nobody answers",
        "+partner": "a partner answers",
        "+arriving": f"a partner arrives at {ROOM_CHANGE_S:g} s and answers",
        "+leaving": f"a partner answers, then leaves at {ROOM_CHANGE_S:g} s",
    }
    kinds = []
    for background in ROOM_SOUNDS:
        for state in PARTNER_STATES:
            if background in NAMED_BACKGROUNDS and state in ("", "+partner"):
                continue  # a bit room too: _named_background_rooms
            partner = {"": False, "+partner": True}.get(state)
            kinds.append(
                RoomKind(
                    background + state,
                    f"{what[state]}; audio only, the {background} sound",
                    "audio",
                    partner,
                    audio=audio_preset(background, state),
                )
            )
    return kinds


def audio_room_names(background: str) -> tuple[str, ...]:
    """The audio rooms of one background, in :data:`PARTNER_STATES` order."""
    return tuple(background + state for state in PARTNER_STATES)


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
        *(_with_sound(kind) for kind in _named_background_rooms()),
        *_audio_only_rooms(),
    ]
)
"""Every named room, in the order commands list them."""

ROOM_NAMES: tuple[str, ...] = tuple(ROOMS)
"""The names of :data:`ROOMS`."""

AUDIO_ROOM_NAMES: tuple[str, ...] = tuple(name for name, kind in ROOMS.items() if kind.audio)
"""The rooms that have an audio-level preset."""

BIT_ROOM_NAMES: tuple[str, ...] = tuple(
    name for name, kind in ROOMS.items() if kind.family != "audio"
)
"""The rooms that exist at the bit level (``simulate``, the bit-level experiments)."""


def room_kind(name: str) -> RoomKind:
    """The registry entry of a room name; ``ValueError`` naming every room if unknown."""
    try:
        return ROOMS[name]
    except KeyError:
        raise ValueError(f"unknown room {name!r}; rooms: {', '.join(ROOM_NAMES)}") from None
