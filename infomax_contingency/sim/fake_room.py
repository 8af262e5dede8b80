"""A simulated room at the level of audio, one window at a time.

Where :mod:`infomax_contingency.sim.world` draws bits, this module makes the sound a
microphone would pick up, so the whole audio path (energies, threshold, bits) runs as it
would on a robot. The room holds:

* a noise floor: white noise at ``noise_floor_db``;
* background sound events (knocks, clatter): a Poisson process of ``event_rate_hz``,
  each a decaying noise burst of ``event_min_s`` .. ``event_max_s`` at ``event_level_db``;
* the robot hearing itself: after each vocalization, its 200 ms chirp
  (:func:`~infomax_contingency.audio.synth.synthesize_chirp`) starts ``self_delay_s`` after the
  start of the next window, at ``self_level_db``;
* a partner, present from ``partner_arrive_s`` until ``partner_leave_s`` (room time),
  who answers a vocalization with probability ``reply_probability``: a speech-like
  reply (noise shaped into syllables at ``syllable_rate_hz``) at ``reply_level_db``,
  starting ``reply_delay_min_s`` .. ``reply_delay_max_s`` after the vocalization and
  lasting ``reply_min_s`` .. ``reply_max_s``.

Conventions: levels are RMS in dB relative to full scale over the sound's duration (so
a window entirely filled by a sound has about that energy); times are seconds of room
time, 0 at the start of the first window; a vocalization decided after window k is
played at the start of window k + 1. The defaults fit the ``robot`` model parameters
(0.5 s windows, self-feedback in the two windows after a vocalization, agent period
1.0 .. 2.5 s after it) and the mic node's fixed threshold of -40 dB
(``config/fake_room.yaml``): a floor at -60 dB, and any window holding 10 ms or more of
a reply, event or chirp above -40 dB. :func:`timing_warnings` checks other parameters.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np

from infomax_contingency.audio.binarizer import Binarizer
from infomax_contingency.audio.bitsource import BitSource
from infomax_contingency.audio.common import PROCESSING_RATE_HZ
from infomax_contingency.audio.energy import window_energies_db, window_samples
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.core.controllers import Controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.sim.loop import run_loop
from infomax_contingency.sim.rooms import AUDIO_ROOM_NAMES, ROOMS

ROBOT_SOUND_S = 0.2
"""Length of the robot's chirp, seconds."""


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

    def __post_init__(self) -> None:
        def fail(name: str, allowed: str) -> None:
            raise ValueError(f"room parameter {name} = {getattr(self, name)!r}: must be {allowed}")

        if isinstance(self.rate_hz, bool) or not isinstance(self.rate_hz, int) or self.rate_hz < 1:
            fail("rate_hz", "a positive whole number of Hz")
        for name in dataclasses.asdict(self):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                fail(name, "a number")
            if not math.isfinite(value):
                fail(name, "finite")
        for name in ("window_s", "event_min_s", "reply_min_s", "syllable_rate_hz"):
            if getattr(self, name) <= 0:
                fail(name, "> 0")
        for name in ("event_rate_hz", "self_delay_s", "reply_delay_min_s"):
            if getattr(self, name) < 0:
                fail(name, ">= 0")
        for name in ("noise_floor_db", "event_level_db", "self_level_db", "reply_level_db"):
            if not -150.0 <= getattr(self, name) <= 0.0:
                fail(name, "a level between -150 and 0 dB (full scale)")
        if not 0.0 <= self.reply_probability <= 1.0:
            fail("reply_probability", "a probability in [0, 1]")
        for low, high in (
            ("event_min_s", "event_max_s"),
            ("reply_min_s", "reply_max_s"),
            ("reply_delay_min_s", "reply_delay_max_s"),
        ):
            if getattr(self, high) < getattr(self, low):
                fail(high, f">= {low} (= {getattr(self, low)})")
        if self.partner_arrive_s >= 0 and 0 <= self.partner_leave_s <= self.partner_arrive_s:
            fail("partner_leave_s", f"> partner_arrive_s (= {self.partner_arrive_s}) or negative")

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


PRESETS: dict[str, dict[str, Any]] = {
    name: dict(ROOMS[name].audio or {}) for name in AUDIO_ROOM_NAMES
}
"""Named rooms (the registry's rooms with an audio-level preset): a responsive partner in a
fairly quiet room; nobody in a quiet room; nobody in a busy room (about half the windows
hold a sound). See :data:`infomax_contingency.sim.rooms.ROOMS`."""


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


def _rms_scaled(x: np.ndarray, level_db: float) -> np.ndarray:
    """``x`` scaled to an RMS of ``level_db`` dB full scale."""
    rms = math.sqrt(float(np.mean(x * x)))
    return x * (10.0 ** (level_db / 20.0) / rms) if rms > 0 else x


class RoomWindow(NamedTuple):
    """One window of the room's sound.

    Attributes:
        index: window number, from 0.
        start_s: room time of the window's first sample, seconds.
        samples: mono float64 samples in [-1, 1].
        partner_present: ground truth at the start of the window.
    """

    index: int
    start_s: float
    samples: np.ndarray
    partner_present: bool


class FakeRoom:
    """The room's sound, window by window, reacting to the robot's vocalizations.

    Deterministic for a given seed and sequence of vocalizations. The noise floor, the
    background events and the partner's replies draw from separate random streams, so
    the background is the same whatever the robot does.

    Args:
        config: room parameters.
        seed: random seed.
    """

    def __init__(self, config: FakeRoomConfig, seed: int = 0) -> None:
        self.config = config
        self.rate = config.rate_hz
        self.window = window_samples(config.rate_hz, config.window_s)
        noise, events, replies = np.random.SeedSequence(seed).spawn(3)
        self._noise_rng = np.random.default_rng(noise)
        self._event_rng = np.random.default_rng(events)
        self._reply_rng = np.random.default_rng(replies)
        chirp = synthesize_chirp(self.rate, ROBOT_SOUND_S, amplitude=1.0)
        self._chirp = _rms_scaled(chirp, config.self_level_db)
        self._floor_rms = 10.0 ** (config.noise_floor_db / 20.0)
        self._sounds: list[tuple[int, np.ndarray]] = []
        self._next_event = self._event_gap()
        self.windows_made = 0
        self.vocalizations = 0
        self.replies = 0
        self.events = 0

    def reconfigure(self, config: FakeRoomConfig) -> None:
        """Go on with new room parameters from the next window on.

        ``rate_hz`` and ``window_s`` must stay (the windows already made keep their
        timing). Levels, the partner's schedule and reply parameters apply to what
        happens from now on: sounds already playing or scheduled (a reply on its way)
        play as they were made. A new ``event_rate_hz`` draws the next background event
        afresh from the start of the next window (exact for a Poisson process).
        Deterministic: the same changes at the same windows give the same room.

        Raises:
            ValueError: ``rate_hz`` or ``window_s`` differs from the room's.
        """
        for name in ("rate_hz", "window_s"):
            if getattr(config, name) != getattr(self.config, name):
                raise ValueError(
                    f"room parameter {name} cannot change while the room runs"
                    f" ({getattr(self.config, name)!r} -> {getattr(config, name)!r})"
                )
        old, self.config = self.config, config
        if config.self_level_db != old.self_level_db:
            chirp = synthesize_chirp(self.rate, ROBOT_SOUND_S, amplitude=1.0)
            self._chirp = _rms_scaled(chirp, config.self_level_db)
        self._floor_rms = 10.0 ** (config.noise_floor_db / 20.0)
        if config.event_rate_hz != old.event_rate_hz:
            self._next_event = self.windows_made * self.window + self._event_gap()

    @property
    def now_s(self) -> float:
        """Room time of the start of the next window, seconds."""
        return self.windows_made * self.window / self.rate

    def _event_gap(self) -> float:
        """Samples until the next background event (inf when there are none)."""
        if self.config.event_rate_hz == 0:
            return math.inf
        return self._event_rng.exponential(self.rate / self.config.event_rate_hz)

    def vocalize(self) -> bool:
        """The robot vocalizes at the start of the next window; True if the partner will reply."""
        start = self.windows_made * self.window
        self.vocalizations += 1
        self._sounds.append((start + round(self.config.self_delay_s * self.rate), self._chirp))
        if not self.config.partner_present_at(self.now_s):
            return False
        if self._reply_rng.random() >= self.config.reply_probability:
            return False
        delay = self._reply_rng.uniform(
            self.config.reply_delay_min_s, self.config.reply_delay_max_s
        )
        length = self._reply_rng.uniform(self.config.reply_min_s, self.config.reply_max_s)
        self._sounds.append((start + round(delay * self.rate), self._reply(length)))
        self.replies += 1
        return True

    def _reply(self, length_s: float) -> np.ndarray:
        """Speech-like noise: syllables of raised-cosine envelope, with short gaps."""
        n = max(1, round(length_s * self.rate))
        syllable = max(2, round(self.rate / self.config.syllable_rate_hz))
        t = np.arange(n) % syllable / syllable  # phase within the syllable, 0 .. 1
        envelope = np.where(t < 0.8, np.sin(np.pi * t / 0.8) ** 2, 0.0)
        loudness = self._reply_rng.uniform(0.6, 1.0, size=n // syllable + 1)
        envelope = envelope * np.repeat(loudness, syllable)[:n]
        return _rms_scaled(
            self._reply_rng.standard_normal(n) * envelope, self.config.reply_level_db
        )

    def _event(self) -> np.ndarray:
        """A background event: a noise burst with a fast attack and exponential decay."""
        length = self._event_rng.uniform(self.config.event_min_s, self.config.event_max_s)
        n = max(1, round(length * self.rate))
        envelope = np.exp(-np.arange(n) / (n / 3.0))
        burst = self._event_rng.standard_normal(n) * envelope
        return _rms_scaled(burst, self.config.event_level_db)

    def next_window(self) -> RoomWindow:
        """The sound of the next window."""
        start = self.windows_made * self.window
        end = start + self.window
        while self._next_event < end:
            self._sounds.append((int(self._next_event), self._event()))
            self.events += 1
            self._next_event += self._event_gap()
        x = self._noise_rng.standard_normal(self.window) * self._floor_rms
        remaining = []
        for sound_start, sound in self._sounds:
            lo, hi = max(start, sound_start), min(end, sound_start + sound.size)
            if lo < hi:
                x[lo - start : hi - start] += sound[lo - sound_start : hi - sound_start]
            if sound_start + sound.size > end:
                remaining.append((sound_start, sound))
        self._sounds = remaining
        window = RoomWindow(
            index=self.windows_made,
            start_s=start / self.rate,
            samples=np.clip(x, -1.0, 1.0),
            partner_present=self.config.partner_present_at(start / self.rate),
        )
        self.windows_made += 1
        return window


def as_transmitted(samples: np.ndarray) -> np.ndarray:
    """The samples as they travel on the ``audio`` topic: float32."""
    return np.asarray(samples, dtype=np.float32)


class AudioObservation(NamedTuple):
    """One window of the fake room as the mic node sees it.

    Attributes:
        y: the window's bit.
        energy_db: the window's energy (of the float32 samples), dB.
        partner_present: the room's ground truth at the start of the window.
    """

    y: int
    energy_db: float
    partner_present: bool


class AudioWorld:
    """The fake room heard through energies and a binarizer, as a loop world.

    Each window's audio is rounded to float32 as on the ``audio`` topic before its
    energy is taken; a window the binarizer spends calibrating (no threshold yet) yields
    no step, as in the mic node. A vocalization is played at the start of the next window.

    Args:
        room: the simulated room.
        binarizer: window energy to bit (a :class:`Binarizer`), or a bit source of
            :func:`~infomax_contingency.audio.bitsource.make_bit_source` (one that needs
            the samples gets them; its ``last_energy_db`` is the window's energy).
    """

    def __init__(self, room: FakeRoom, binarizer: Binarizer | BitSource) -> None:
        self.room = room
        self.binarizer = binarizer

    def observe(self) -> AudioObservation | None:
        """The next window's bit, energy and ground truth (None while calibrating)."""
        window = self.room.next_window()
        samples = as_transmitted(window.samples).astype(np.float64)
        if getattr(self.binarizer, "needs_samples", False):
            y = self.binarizer.push_window(samples)
            energy = self.binarizer.last_energy_db
        else:
            energy = float(
                window_energies_db(samples, self.room.rate, self.room.config.window_s)[0]
            )
            y = self.binarizer.push(energy)
        if y is None:
            return None
        return AudioObservation(int(y), energy, window.partner_present)

    def act(self, u: int) -> None:
        """Vocalize at the start of the next window if ``u`` is 1."""
        if u:
            self.room.vocalize()


@dataclasses.dataclass(frozen=True)
class AudioStepRecord:
    """One step of :func:`simulate_audio_loop`.

    Attributes:
        t: step number, from 1.
        energy_db: the window's energy, dB.
        y: the window's bit.
        u: the decision taken after it (1 = vocalize).
        belief: P(S=1) after counting y.
        partner_present: the room's ground truth at the start of the window.
    """

    t: int
    energy_db: float
    y: int
    u: int
    belief: float
    partner_present: bool


def iter_audio_loop(
    controller: Controller,
    room: FakeRoom,
    binarizer: Binarizer | BitSource,
    steps: int | None,
    memory: int = 0,
) -> Iterator[AudioStepRecord]:
    """The streaming form of :func:`simulate_audio_loop` (``steps = None``: without end)."""
    params = controller.params
    for step in run_loop(AudioWorld(room, binarizer), controller, steps, memory=memory):
        seen = step.observation
        yield AudioStepRecord(
            step.t,
            seen.energy_db,
            seen.y,
            step.u,
            step.statistic.belief(params),
            seen.partner_present,
        )


def simulate_audio_loop(
    controller: Controller,
    room: FakeRoom,
    binarizer: Binarizer | BitSource,
    steps: int,
    memory: int = 0,
) -> list[AudioStepRecord]:
    """The node graph's lockstep loop, offline: room -> energy -> bit -> decision -> room.

    The audio is rounded to float32 as on the ``audio`` topic, so the energies, bits,
    decisions and beliefs equal those of the graph (mic, controller and belief nodes
    against the fake audio node in lockstep) for the same seed, threshold and memory.
    Calibration windows (a binarizer without a threshold) yield no step, as in the mic node.
    The controller is used as it is (not reset).
    """
    return list(iter_audio_loop(controller, room, binarizer, steps, memory=memory))
