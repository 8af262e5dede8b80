"""The settings of the simulated room (:class:`FakeRoomConfig`): its sources and levels.

:class:`~infomax_contingency.sim.fake_room.FakeRoom` makes the sound a microphone would pick
up from them, one window at a time. The room holds (the sounds themselves are made in
:mod:`infomax_contingency.sim.room_sounds`):

* a noise floor at ``noise_floor_db`` of spectrum ``floor_spectrum`` (white, pink or
  hvac, see :data:`~infomax_contingency.sim.room_sounds.FLOOR_SPECTRA`);
* background sound events (knocks, clatter): a Poisson process of ``event_rate_hz``,
  each a decaying noise burst of ``event_min_s`` .. ``event_max_s`` at ``event_level_db``;
  door slams (``door_rate_hz``, at ``door_level_db``) and walks of 4 .. 10 footsteps
  0.45 .. 0.6 s apart (``footsteps_rate_hz`` walks per second, each step at
  ``footsteps_level_db``);
* distant talkers (babble): ``babble_talkers`` people each talking in utterances of
  1 .. 4 s with pauses of 1 s on average (exponential), speech-like sound low-passed at
  ``babble_cutoff_hz``, together at a long-term level of ``babble_level_db``;
* a TV (``tv_on``): a speech-like programme in stretches of 1.5 .. 6 s with pauses of
  0.2 .. 1.2 s, low-passed at 4 kHz (a small loudspeaker), at a long-term level of
  ``tv_level_db``;
* (the newer rooms) distant talkers and a TV that speak sentences rendered by espeak-ng
  (``babble_voice`` / ``tv_voice`` ``tts``, :mod:`~infomax_contingency.sim.tts`), talkers
  who join one every ``babble_join_s`` seconds (a crowd that grows), a TV switched on at
  ``tv_start_s``; music (``music_on``, bars of chords, bass and hi-hat at
  ``music_level_db``), a mains hum (``hum_on``, 50 Hz and harmonics at ``hum_level_db``),
  traffic passing (``traffic_rate_hz`` swells of 3-8 s at ``traffic_level_db``) and
  typing (``typing_rate_hz`` bursts of 2-8 s of key clicks at ``typing_level_db``); a
  partner who speaks espeak-ng sentences (``reply_voice`` ``tts``);
* (the later held-out rooms, :mod:`infomax_contingency.sim.household_streams`)
  ``children_talkers`` children (espeak-ng's children's voices) talking and shouting in
  bursts of 0.4-2.5 s at ``children_level_db`` (+-4 dB a burst), toys squeaking or
  rattling (``toy_rate_hz`` a second, at ``toy_level_db``), a dog barking in clusters of
  1-5 barks of 0.1-0.3 s (``bark_rate_hz`` clusters a second, each bark at
  ``bark_level_db``), a washing machine (``washer_on``: the motor's whine and the drum
  turning at 0.8-1.2 Hz at a long-term ``washer_level_db``, and every 20-30 s a spin of
  6-12 s, a rising whine at ``washer_spin_level_db`` over it) and a vacuum cleaner in the
  next room (``vacuum_on``: on for 5-25 s, off for 5-20 s, at ``vacuum_level_db`` while on);
* the robot hearing itself: after each vocalization, its 200 ms chirp
  (:func:`~infomax_contingency.audio.synth.synthesize_chirp`) starts ``self_delay_s`` after the
  start of the next window, at ``self_level_db``; with ``reverb_rt60_s > 0`` followed by
  the room's echo of it (:func:`~infomax_contingency.sim.room_sounds.reverb_tail`, 60 dB
  decay in ``reverb_rt60_s``) at ``reverb_level_db``;
* the robot speaking (a TTS-like utterance through the room's loudspeaker): after a
  vocalization, with probability ``robot_speech_probability``, it says something
  (speech-like sound at ``robot_speech_level_db``) starting ``robot_speech_delay_s``
  after the vocalization and lasting ``robot_speech_min_s`` .. ``robot_speech_max_s``;
  and now and then on its own, ``robot_speech_rate_hz`` utterances per second (a
  Poisson process), from random streams of their own. After a vocalization it falls in the
  agent period: to the model it sounds like a partner's reply unless it is declared as the
  robot's own sound (:attr:`~infomax_contingency.sim.fake_room.RoomWindow.robot_sound`;
  fake_audio_node publishes it on ``self_sound``);
* a partner, present from ``partner_arrive_s`` until ``partner_leave_s`` (room time),
  who answers a vocalization with probability ``reply_probability``: a reply at
  ``reply_level_db``, starting ``reply_delay_min_s`` .. ``reply_delay_max_s`` after the
  vocalization and lasting ``reply_min_s`` .. ``reply_max_s``; with ``reply_voice``
  ``noise``, noise shaped into syllables at ``syllable_rate_hz``, with ``speech`` a
  speech-like voice (:func:`~infomax_contingency.sim.room_sounds.speech_like`: voiced
  syllables at about ``syllable_rate_hz`` with 10-30 ms onsets, formants, one pitch).

Conventions: levels are RMS in dB relative to full scale (dB FS): of a transient sound
(event, door, footstep, chirp, echo, reply) over the sound's duration, so a window entirely
filled by it has about that energy; of a continuous source (floor, babble, TV) over all
time, pauses included
(:meth:`~infomax_contingency.sim.fake_room.FakeRoom.measured_levels_db` measures both);
times are seconds of room time, 0 at the start of the first window; a vocalization decided
after window k is played at the start of window k + 1. The defaults fit the ``robot`` model
parameters (0.5 s windows, self-feedback in the two windows after a vocalization, agent
period 1.0 .. 2.5 s after it) and the mic node's fixed threshold of -40 dB
(``config/fake_room.yaml``): a floor at -60 dB, and any window holding 10 ms or more of a
reply, event or chirp above -40 dB. :func:`timing_warnings` checks other parameters. Every
source beyond the white floor, knocks, chirp and noise replies is off by default, so a
configuration that does not name one sounds as before, sample for sample. The presets and
their levels: :data:`infomax_contingency.sim.rooms.ROOMS` and docs/RESULTS.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

from infomax_contingency.audio.common import PROCESSING_RATE_HZ
from infomax_contingency.core.model import ModelParams
from infomax_contingency.limits import finite
from infomax_contingency.sim.room_sounds import FLOOR_SPECTRA
from infomax_contingency.sim.rooms import AUDIO_ROOM_NAMES, ROOMS

ROBOT_SOUND_S = 0.2
"""Length of the robot's chirp, seconds."""

REPLY_VOICES = ("noise", "speech", "tts")
"""How a partner's reply sounds (see the module docstring)."""

SPEECH_VOICES = ("synthetic", "tts")
"""How distant talkers and the TV speak: ``synthetic`` (the speech-like bank of
:func:`~infomax_contingency.sim.room_sounds.speech_bank`) or ``tts`` (sentences spoken by
espeak-ng, :func:`~infomax_contingency.sim.room_sounds.tts_voices`)."""

CONTINUOUS_SOURCES = ("floor", "babble", "tv", "music", "hum", "washer")
"""Sources whose level is their long-term RMS (pauses included)."""
TRANSIENT_SOURCES = (
    "event", "door", "footstep", "self", "echo", "reply", "robot_speech", "traffic", "typing",
    "children", "toy", "bark", "spin", "vacuum"
)
"""Sources whose level is the RMS over each sound's duration."""


@dataclasses.dataclass(frozen=True)
class FakeRoomConfig:
    """Parameters of the simulated room (see the module docstring for their meaning).

    A negative ``partner_arrive_s`` means there is no partner; a negative
    ``partner_leave_s`` means the partner never leaves.
    """

    rate_hz: int = PROCESSING_RATE_HZ
    window_s: float = 0.5
    noise_floor_db: float = -60.0
    event_rate_hz: float = 0.1
    event_level_db: float = -25.0
    event_min_s: float = 0.1
    event_max_s: float = 0.4
    self_delay_s: float = 0.15
    self_level_db: float = -20.0
    partner_arrive_s: float = 0.0
    partner_leave_s: float = -1.0
    reply_probability: float = 0.9
    reply_level_db: float = -20.0
    reply_delay_min_s: float = 1.0
    reply_delay_max_s: float = 1.4
    reply_min_s: float = 0.6
    reply_max_s: float = 1.0
    syllable_rate_hz: float = 4.0
    floor_spectrum: str = "white"
    reply_voice: str = "noise"
    door_rate_hz: float = 0.0
    door_level_db: float = -20.0
    footsteps_rate_hz: float = 0.0
    footsteps_level_db: float = -35.0
    babble_talkers: int = 0
    babble_level_db: float = -40.0
    babble_cutoff_hz: float = 1000.0
    tv_on: bool = False
    tv_level_db: float = -35.0
    reverb_rt60_s: float = 0.0
    reverb_level_db: float = -35.0
    babble_voice: str = "synthetic"
    babble_join_s: float = 0.0
    tv_voice: str = "synthetic"
    tv_start_s: float = 0.0
    music_on: bool = False
    music_level_db: float = -35.0
    hum_on: bool = False
    hum_level_db: float = -45.0
    traffic_rate_hz: float = 0.0
    traffic_level_db: float = -35.0
    typing_rate_hz: float = 0.0
    typing_level_db: float = -40.0
    robot_speech_probability: float = 0.0
    robot_speech_rate_hz: float = 0.0
    robot_speech_delay_s: float = 1.0
    robot_speech_min_s: float = 0.6
    robot_speech_max_s: float = 1.0
    robot_speech_level_db: float = -20.0
    children_talkers: int = 0
    children_level_db: float = -33.0
    toy_rate_hz: float = 0.0
    toy_level_db: float = -38.0
    bark_rate_hz: float = 0.0
    bark_level_db: float = -30.0
    washer_on: bool = False
    washer_level_db: float = -40.0
    washer_spin_level_db: float = -34.0
    vacuum_on: bool = False
    vacuum_level_db: float = -36.0

    def __post_init__(self) -> None:  # noqa: C901
        def fail(name: str, allowed: str) -> None:
            raise ValueError(f"room parameter {name} = {getattr(self, name)!r}: must be {allowed}")

        if isinstance(self.rate_hz, bool) or not isinstance(self.rate_hz, int) or self.rate_hz < 1:
            fail("rate_hz", "a positive whole number of Hz")
        counts = (("babble_talkers", "talkers", 100), ("children_talkers", "children", 10))
        for name, who, most in counts:
            count = getattr(self, name)
            if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count <= most:
                fail(name, f"a whole number of {who} in 0 .. {most}")
        for name in ("tv_on", "music_on", "hum_on", "washer_on", "vacuum_on"):
            if not isinstance(getattr(self, name), bool):
                fail(name, "true or false")
        for name in ("babble_voice", "tv_voice"):
            if getattr(self, name) not in SPEECH_VOICES:
                fail(name, f"one of {', '.join(SPEECH_VOICES)}")
        if self.floor_spectrum not in FLOOR_SPECTRA:
            fail("floor_spectrum", f"one of {', '.join(FLOOR_SPECTRA)}")
        if self.reply_voice not in REPLY_VOICES:
            fail("reply_voice", f"one of {', '.join(REPLY_VOICES)}")
        for name in dataclasses.asdict(self):
            if name in _NON_NUMBER_FIELDS:
                continue
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                fail(name, "a number")
            if not finite(value):
                fail(name, "finite")
        self._check_bounds(fail)
        if not 0.0 <= self.reverb_rt60_s <= 5.0:
            fail("reverb_rt60_s", "a reverberation time in 0 .. 5 s (0: no echo)")
        if not 0.0 < self.babble_cutoff_hz:
            fail("babble_cutoff_hz", "> 0 Hz")
        for name in _LEVEL_FIELDS:
            if not -150.0 <= getattr(self, name) <= 0.0:
                fail(name, "a level between -150 and 0 dB (full scale)")
        for name in ("reply_probability", "robot_speech_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                fail(name, "a probability in [0, 1]")
        for low, high in (
            ("event_min_s", "event_max_s"),
            ("reply_min_s", "reply_max_s"),
            ("reply_delay_min_s", "reply_delay_max_s"),
            ("robot_speech_min_s", "robot_speech_max_s"),
        ):
            if getattr(self, high) < getattr(self, low):
                fail(high, f">= {low} (= {getattr(self, low)})")
        if self.partner_arrive_s >= 0 and 0 <= self.partner_leave_s <= self.partner_arrive_s:
            fail("partner_leave_s", f"> partner_arrive_s (= {self.partner_arrive_s}) or negative")

    def _check_bounds(self, fail: Callable[[str, str], None]) -> None:
        """Signs and upper bounds of the rates, lengths and delays (``fail``: the error)."""
        for name in ("window_s", "event_min_s", "reply_min_s", "syllable_rate_hz",
                     "robot_speech_min_s"):
            if getattr(self, name) <= 0:
                fail(name, "> 0")
        for name in _NON_NEGATIVE_FIELDS:
            if getattr(self, name) < 0:
                fail(name, ">= 0")
        for name in _EVENT_RATE_FIELDS:
            if getattr(self, name) > MAX_EVENT_RATE_HZ:
                fail(name, f"at most {MAX_EVENT_RATE_HZ:g} a second")
        if self.syllable_rate_hz > MAX_SYLLABLE_RATE_HZ:
            fail("syllable_rate_hz", f"at most {MAX_SYLLABLE_RATE_HZ:g} a second")
        for name in _ONE_SOUND_FIELDS:
            if getattr(self, name) > MAX_ONE_SOUND_S:
                fail(name, f"at most {MAX_ONE_SOUND_S:g} s")

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> FakeRoomConfig:
        """A named room (:data:`PRESETS`) with some fields overridden."""
        if name not in PRESETS:
            raise ValueError(f"unknown room {name!r}; rooms: {', '.join(PRESETS)}")
        return cls(**{**PRESETS[name], **overrides})

    def partner_present_at(self, time_s: float) -> bool:
        """Is the partner in the room at room time ``time_s``."""
        if self.partner_arrive_s < 0 or time_s < self.partner_arrive_s:
            return False
        return self.partner_leave_s < 0 or time_s < self.partner_leave_s


_NON_NEGATIVE_FIELDS = (
    "event_rate_hz",
    "self_delay_s",
    "reply_delay_min_s",
    "door_rate_hz",
    "footsteps_rate_hz",
    "babble_join_s",
    "tv_start_s",
    "traffic_rate_hz",
    "typing_rate_hz",
    "robot_speech_delay_s",
    "robot_speech_rate_hz",
    "toy_rate_hz",
    "bark_rate_hz",
)
"""Fields of :class:`FakeRoomConfig` that must be >= 0."""

MAX_EVENT_RATE_HZ = 100.0
"""Most sounds a second of one kind (events, doors, walks, ...): the synthesis draws each."""

MAX_SYLLABLE_RATE_HZ = 50.0
"""Most syllables a second in a reply."""

MAX_ONE_SOUND_S = 60.0
"""s, the longest a single sound (an event, a reply, an utterance) or its delay may be."""

_EVENT_RATE_FIELDS = tuple(name for name in _NON_NEGATIVE_FIELDS if name.endswith("_rate_hz"))
"""Sounds a second, each at most :data:`MAX_EVENT_RATE_HZ`."""

_ONE_SOUND_FIELDS = (
    "event_min_s",
    "event_max_s",
    "self_delay_s",
    "reply_delay_min_s",
    "reply_delay_max_s",
    "reply_min_s",
    "reply_max_s",
    "robot_speech_delay_s",
    "robot_speech_min_s",
    "robot_speech_max_s",
)
"""Lengths and delays of one sound, s, each at most :data:`MAX_ONE_SOUND_S`."""

_LEVEL_FIELDS = (
    "noise_floor_db",
    "event_level_db",
    "self_level_db",
    "reply_level_db",
    "door_level_db",
    "footsteps_level_db",
    "babble_level_db",
    "tv_level_db",
    "reverb_level_db",
    "music_level_db",
    "hum_level_db",
    "traffic_level_db",
    "typing_level_db",
    "robot_speech_level_db",
    "children_level_db",
    "toy_level_db",
    "bark_level_db",
    "washer_level_db",
    "washer_spin_level_db",
    "vacuum_level_db",
)
"""Fields of :class:`FakeRoomConfig` that are levels, dB FS (-150 .. 0)."""

_NON_NUMBER_FIELDS = frozenset(
    {
        "rate_hz", "babble_talkers", "tv_on", "floor_spectrum", "reply_voice", "babble_voice",
        "tv_voice", "music_on", "hum_on", "children_talkers", "washer_on", "vacuum_on",
    }
)
"""Fields checked on their own in :meth:`FakeRoomConfig.__post_init__` (not plain numbers)."""


PRESETS: dict[str, dict[str, Any]] = {
    name: dict(ROOMS[name].audio or {}) for name in AUDIO_ROOM_NAMES
}
"""Named rooms (the registry's rooms with an audio-level preset): ``responsive`` (a
partner in a fairly quiet room), ``silent`` (nobody, a quiet room), ``noisy`` (nobody, a
busy room: about half the windows hold a sound), and the rooms that sound like rooms,
``quiet``, ``office``, ``poster-session``, ``tv-on`` and the newer and held-out rooms
with the partner absent, present (``+partner``), arriving (``+arriving``) or leaving
(``+leaving``). See :data:`infomax_contingency.sim.rooms.ROOMS`."""


def timing_warnings(config: FakeRoomConfig, params: ModelParams) -> list[str]:
    """Ways in which the room's timing does not match the model's periods (empty: none).

    The robot's sound should end inside the self-feedback period, and replies should
    lie inside the agent period, counted from the vocalization (start of a window).
    """
    warnings = []
    if not math.isclose(config.window_s, params.dt):
        warnings.append(
            f"window_s = {config.window_s} s differs from the model's dt = {params.dt} s"
        )
    dt = config.window_s
    self_end = config.self_delay_s + ROBOT_SOUND_S
    if config.reverb_rt60_s > 0:
        self_end += config.reverb_rt60_s + 0.01  # the echo, to 60 dB down
    if self_end > (params.ts2 + 1) * dt:
        warnings.append(
            f"the robot's sound ends {self_end:.2f} s after the vocalization, after the"
            f" self-feedback period (ends at {(params.ts2 + 1) * dt:.2f} s)"
        )
    if config.reply_delay_min_s < params.ta1 * dt:
        warnings.append(
            f"replies may start {config.reply_delay_min_s:.2f} s after the vocalization, before"
            f" the agent period ({params.ta1 * dt:.2f} s)"
        )
    reply_end = config.reply_delay_max_s + config.reply_max_s
    if reply_end > (params.ta2 + 1) * dt:
        warnings.append(
            f"replies may last until {reply_end:.2f} s after the vocalization, after the"
            f" agent period (ends at {(params.ta2 + 1) * dt:.2f} s)"
        )
    return warnings


def partner_times(room: str, leave_s: float | None = None) -> dict[str, float]:
    """A named room's ``partner_arrive_s`` and ``partner_leave_s`` (room time, s; -1: never).

    ``leave_s`` moves the departure (negative: the partner stays); None keeps the room's.
    """
    preset = FakeRoomConfig.preset(room)
    leave = preset.partner_leave_s if leave_s is None else leave_s
    return {"partner_arrive_s": preset.partner_arrive_s,
            "partner_leave_s": leave if leave >= 0 else -1.0}  # fmt: skip
