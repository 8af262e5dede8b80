"""A simulated room at the level of audio, one window at a time (:class:`FakeRoom`).

Where :mod:`infomax_contingency.sim.world` draws bits, this module makes the sound a
microphone would pick up, so the whole audio path (energies, threshold, bits) runs as it
would on a robot. Its sources, levels and timing are the settings of
:class:`~infomax_contingency.sim.room_config.FakeRoomConfig` (described there); the sounds
themselves are made in :mod:`infomax_contingency.sim.room_sounds` (and, for the later
held-out rooms, :mod:`infomax_contingency.sim.household_streams`); the room heard through a
bit source, in the loop with a controller, is :mod:`infomax_contingency.sim.audio_loop`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import numpy as np

from infomax_contingency.audio.energy import window_samples
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.sim import room_sounds
from infomax_contingency.sim.household_sounds import toy_sound
from infomax_contingency.sim.household_streams import HOUSEHOLD_SOURCES, household_streams
from infomax_contingency.sim.room_config import CONTINUOUS_SOURCES, ROBOT_SOUND_S, FakeRoomConfig
from infomax_contingency.sim.room_sounds import NoiseFloor, rms_scaled

BABBLE_UTTERANCE_S = (1.0, 4.0)
"""Shortest and longest utterance of a distant talker, seconds (uniform)."""
BABBLE_PAUSE_MEAN_S = 1.0
"""Mean pause between a distant talker's utterances, seconds (exponential)."""
TV_STRETCH_S = (1.5, 6.0)
"""Shortest and longest stretch of TV speech, seconds (uniform)."""
TV_PAUSE_S = (0.2, 1.2)
"""Shortest and longest pause of the TV programme, seconds (uniform)."""
TV_CUTOFF_HZ = 4000.0
"""Low-pass of the TV's small loudspeaker, Hz."""
FOOTSTEPS_PER_WALK = (4, 10)
"""Fewest and most footsteps of a walk past the robot."""
FOOTSTEP_INTERVAL_S = (0.45, 0.6)
"""Shortest and longest time between two footsteps, seconds (uniform per walk)."""

class RoomWindow(NamedTuple):
    """One window of the room's sound.

    Attributes:
        index: window number, from 0.
        start_s: room time of the window's first sample, seconds.
        samples: mono float64 samples in [-1, 1].
        partner_present: ground truth at the start of the window.
        robot_sound: the window overlaps the robot's speech (sound it declares as its
            own: the window is observed but is no evidence, see
            :class:`~infomax_contingency.core.model.Withheld`).
    """

    index: int
    start_s: float
    samples: np.ndarray
    partner_present: bool
    robot_sound: bool = False


class _Sound(NamedTuple):
    """A sound scheduled in the room: first sample (room samples), samples, its source."""

    start: int
    samples: np.ndarray
    source: str


_LIVE_FIELDS = frozenset({
    "noise_floor_db", "event_rate_hz", "event_level_db", "event_min_s", "event_max_s",
    "self_delay_s", "self_level_db", "partner_arrive_s", "partner_leave_s",
    "reply_probability", "reply_level_db", "reply_delay_min_s", "reply_delay_max_s",
    "reply_min_s", "reply_max_s", "syllable_rate_hz", "robot_speech_probability",
    "robot_speech_rate_hz",
    "robot_speech_delay_s", "robot_speech_min_s", "robot_speech_max_s", "robot_speech_level_db",
})
"""Fields of :class:`FakeRoomConfig` that :meth:`FakeRoom.reconfigure` may change."""

_FIXED_WHILE_RUNNING = tuple(
    field.name for field in dataclasses.fields(FakeRoomConfig) if field.name not in _LIVE_FIELDS
)


class _SoundStream:
    """A background source: sounds at random times from their own random stream.

    ``first_gap()`` gives the start of the first sound (samples, may be negative: a
    sound already under way at time 0); ``make()`` the next sound's parts as
    ``(offset from its start in samples, samples)``; ``gap(parts)`` the samples from this
    sound's start to the next one's.
    """

    def __init__(
        self,
        source: str,
        first_gap: Callable[[], float],
        make: Callable[[], list[tuple[int, np.ndarray]]],
        gap: Callable[[list[tuple[int, np.ndarray]]], float],
    ) -> None:
        self.source = source
        self.make = make
        self.gap = gap
        self.next_start = first_gap()
        self.sounds = 0

    def due(self, end: int) -> Iterator[_Sound]:
        """The sounds that start before sample ``end`` and were not given out yet."""
        while self.next_start < end:
            parts = self.make()
            start = int(self.next_start)
            for offset, samples in parts:
                yield _Sound(start + offset, samples, self.source)
            self.sounds += 1
            self.next_start += self.gap(parts)


class FakeRoom:
    """The room's sound, window by window, reacting to the robot's vocalizations.

    Deterministic for a given seed and sequence of vocalizations. The noise floor, each
    kind of background sound and the partner's replies draw from separate random
    streams, so the background is the same whatever the robot does.

    Args:
        config: room parameters.
        seed: random seed.
        meter: keep the energy of every source apart (:meth:`measured_levels_db`);
            the room sounds the same with or without.
    """

    def __init__(self, config: FakeRoomConfig, seed: int = 0, meter: bool = False) -> None:
        self.config = config
        self.rate = config.rate_hz
        self.window = window_samples(config.rate_hz, config.window_s)
        # the first eight as ever, then the newer rooms' sources, then the robot's speech,
        # then the later rooms' (spawned after: the first 13 streams stay as they were)
        streams = np.random.SeedSequence(seed).spawn(13 + len(HOUSEHOLD_SOURCES))
        (noise, events, replies, doors, steps, babble, tv, reverb, music, traffic, typing,
         speech, chatter) = (
            np.random.default_rng(stream) for stream in streams[:13]
        )
        self._speech_rng = speech
        self._chatter_rng = chatter
        self._next_chatter = self._chatter_gap()
        """Room sample of the robot's next utterance of its own (inf: none)."""
        self._robot_f0 = float(speech.uniform(90.0, 130.0))
        self._robot_speech: list[tuple[int, int]] = []
        """The robot's utterances still to come or under way: (first, end) room samples."""
        self._event_rng = events
        self._reply_rng = replies
        chirp = synthesize_chirp(self.rate, ROBOT_SOUND_S, amplitude=1.0)
        self._chirp = rms_scaled(chirp, config.self_level_db)
        self._echo = (
            rms_scaled(
                room_sounds.reverb_tail(chirp, config.reverb_rt60_s, self.rate, reverb),
                config.reverb_level_db,
            )
            if config.reverb_rt60_s > 0
            else None
        )
        self._partner_f0 = replies.uniform(100.0, 250.0) if config.reply_voice == "speech" else None
        self._partner_tts = (
            room_sounds.tts_voices(self.rate, self.rate)[int(replies.integers(6))]
            if config.reply_voice == "tts"
            else None
        )
        self._floor = NoiseFloor(config.floor_spectrum, config.noise_floor_db, noise)
        self._sounds: list[_Sound] = []
        self._streams = self._background_streams(events, doors, steps, babble, tv)
        self._streams += _newer_streams(self, music, traffic, typing)
        household = dict(zip(HOUSEHOLD_SOURCES, streams[13:], strict=True))
        self._streams += [
            _SoundStream(*spec) for spec in household_streams(config, self.rate, streams[13:])
        ]
        if config.toy_rate_hz > 0:
            toys = np.random.default_rng(household["toy"])
            self._streams.append(_poisson_sounds(self, "toy", toys, config.toy_rate_hz,
                                                 config.toy_level_db, toy_sound))  # fmt: skip
        self.windows_made = 0
        self.vocalizations = 0
        self.replies = 0
        self.robot_utterances = 0
        self._meter: dict[str, list[float]] | None = {} if meter else None

    @property
    def events(self) -> int:
        """Background events (knocks) so far."""
        return self._streams[0].sounds

    def reconfigure(self, config: FakeRoomConfig) -> None:
        """Go on with new room parameters from the next window on.

        Live: the levels of the floor, the knocks, the robot's chirp and the partner's
        replies, the knocks' rate and lengths, the partner's schedule and reply
        parameters. They apply to what happens from now on: sounds already playing or
        scheduled (a reply on its way) play as they were made. A new ``event_rate_hz``
        draws the next knock afresh from the start of the next window (exact for a
        Poisson process). Deterministic: the same changes at the same windows give the
        same room. The other fields (timing, the floor's spectrum, the background
        sources a preset sets up: talkers, TV, doors, footsteps, echo) must stay.

        Raises:
            ValueError: a field that must stay differs from the room's.
        """
        for name in _FIXED_WHILE_RUNNING:
            if getattr(config, name) != getattr(self.config, name):
                raise ValueError(
                    f"room parameter {name} cannot change while the room runs"
                    f" ({getattr(self.config, name)!r} -> {getattr(config, name)!r})"
                )
        old, self.config = self.config, config
        if config.self_level_db != old.self_level_db:
            chirp = synthesize_chirp(self.rate, ROBOT_SOUND_S, amplitude=1.0)
            self._chirp = rms_scaled(chirp, config.self_level_db)
        self._floor.rms = 10.0 ** (config.noise_floor_db / 20.0)
        if config.robot_speech_rate_hz != old.robot_speech_rate_hz:
            self._next_chatter = self.windows_made * self.window + self._chatter_gap()
        if config.event_rate_hz != old.event_rate_hz:
            knocks = self._streams[0]
            knocks.gap = self._poisson_gap(self._event_rng, config.event_rate_hz)
            knocks.next_start = self.windows_made * self.window + knocks.gap()

    @property
    def now_s(self) -> float:
        """Room time of the start of the next window, seconds."""
        return self.windows_made * self.window / self.rate

    def _poisson_gap(self, rng: np.random.Generator, rate_hz: float) -> Callable[..., float]:
        """Samples from one sound's start to the next one's: exponential, mean 1 / rate."""

        def gap(*_: Any) -> float:
            return math.inf if rate_hz == 0 else rng.exponential(self.rate / rate_hz)

        return gap

    def _background_streams(
        self,
        events: np.random.Generator,
        doors: np.random.Generator,
        steps: np.random.Generator,
        babble: np.random.Generator,
        tv: np.random.Generator,
    ) -> list[_SoundStream]:
        """Knocks (always first: :attr:`events`), doors, footsteps, each talker, the TV."""
        config, rate = self.config, self.rate
        knock_gap = self._poisson_gap(events, config.event_rate_hz)
        streams = [_SoundStream("event", knock_gap, lambda: [(0, self._event())], knock_gap)]
        if config.door_rate_hz > 0:
            door_gap = self._poisson_gap(doors, config.door_rate_hz)

            def door() -> list[tuple[int, np.ndarray]]:
                return [(0, rms_scaled(room_sounds.door_slam(rate, doors), config.door_level_db))]

            streams.append(_SoundStream("door", door_gap, door, door_gap))
        if config.footsteps_rate_hz > 0:
            walk_gap = self._poisson_gap(steps, config.footsteps_rate_hz)
            streams.append(_SoundStream("footstep", walk_gap, lambda: self._walk(steps), walk_gap))
        if config.babble_talkers > 0:
            mean_on = 0.5 * sum(BABBLE_UTTERANCE_S)
            duty = mean_on / (mean_on + BABBLE_PAUSE_MEAN_S)
            level = config.babble_level_db - 10.0 * math.log10(config.babble_talkers * duty)
            for k in range(config.babble_talkers):
                talker = np.random.default_rng(babble.integers(2**63))
                streams.append(self._talker(talker, level, k * config.babble_join_s))
        if config.tv_on:
            mean_on, mean_off = 0.5 * sum(TV_STRETCH_S), 0.5 * sum(TV_PAUSE_S)
            duty = mean_on / (mean_on + mean_off)
            streams.append(self._tv(tv, config.tv_level_db - 10.0 * math.log10(duty)))
        return streams

    def _excerpt(
        self, rng: np.random.Generator, voice: np.ndarray, seconds: float, level: float
    ) -> np.ndarray:
        """``seconds`` of a voice of the speech bank at ``level`` dB FS."""
        n = max(1, round(seconds * self.rate))
        return rms_scaled(room_sounds.speech_excerpt(voice, n, self.rate, rng), level)

    def _talker(self, rng: np.random.Generator, level: float, join_s: float = 0.0) -> _SoundStream:
        """A distant talker: utterances of :data:`BABBLE_UTTERANCE_S` with exponential pauses.

        ``join_s > 0``: the talker starts talking at that room time (a crowd that grows).
        """
        bank = room_sounds.voice_bank(
            self.config.babble_voice, self.rate, self.config.syllable_rate_hz,
            self.config.babble_cutoff_hz,
        )
        voice = bank[int(rng.integers(len(bank)))]
        low, high = BABBLE_UTTERANCE_S
        cycle = (0.5 * (low + high) + BABBLE_PAUSE_MEAN_S) * self.rate

        def utterance() -> list[tuple[int, np.ndarray]]:
            return [(0, self._excerpt(rng, voice, rng.uniform(low, high), level))]

        def gap(parts: list[tuple[int, np.ndarray]]) -> float:
            return parts[0][1].size + rng.exponential(BABBLE_PAUSE_MEAN_S * self.rate)

        if join_s > 0:
            return _SoundStream("babble", lambda: join_s * self.rate, utterance, gap)
        return _SoundStream("babble", lambda: -rng.uniform(0.0, cycle), utterance, gap)

    def _tv(self, rng: np.random.Generator, level: float) -> _SoundStream:
        """The TV programme: stretches of :data:`TV_STRETCH_S`, pauses of :data:`TV_PAUSE_S`."""
        bank = room_sounds.voice_bank(
            self.config.tv_voice, self.rate, self.config.syllable_rate_hz, TV_CUTOFF_HZ
        )
        voice = bank[int(rng.integers(len(bank)))]
        start_s = self.config.tv_start_s

        def stretch() -> list[tuple[int, np.ndarray]]:
            return [(0, self._excerpt(rng, voice, rng.uniform(*TV_STRETCH_S), level))]

        def gap(parts: list[tuple[int, np.ndarray]]) -> float:
            return parts[0][1].size + rng.uniform(*TV_PAUSE_S) * self.rate

        if start_s > 0:  # switched on then
            return _SoundStream("tv", lambda: start_s * self.rate, stretch, gap)
        return _SoundStream(
            "tv", lambda: -rng.uniform(0.0, TV_STRETCH_S[1] * self.rate), stretch, gap
        )

    def _walk(self, rng: np.random.Generator) -> list[tuple[int, np.ndarray]]:
        """Footsteps of one walk past the robot, each at ``footsteps_level_db``."""
        count = int(rng.integers(FOOTSTEPS_PER_WALK[0], FOOTSTEPS_PER_WALK[1] + 1))
        interval = rng.uniform(*FOOTSTEP_INTERVAL_S) * self.rate
        level = self.config.footsteps_level_db
        return [
            (round(k * interval), rms_scaled(room_sounds.footstep(self.rate, rng), level))
            for k in range(count)
        ]

    def vocalize(self) -> bool:
        """The robot vocalizes at the start of the next window; True if the partner will reply."""
        start = self.windows_made * self.window
        self.vocalizations += 1
        sound_start = start + round(self.config.self_delay_s * self.rate)
        self._sounds.append(_Sound(sound_start, self._chirp, "self"))
        if self._echo is not None:
            self._sounds.append(_Sound(sound_start, self._echo, "echo"))
        self._maybe_speak(start)
        if not self.config.partner_present_at(self.now_s):
            return False
        if self._reply_rng.random() >= self.config.reply_probability:
            return False
        delay = self._reply_rng.uniform(
            self.config.reply_delay_min_s, self.config.reply_delay_max_s
        )
        length = self._reply_rng.uniform(self.config.reply_min_s, self.config.reply_max_s)
        self._sounds.append(_Sound(start + round(delay * self.rate), self._reply(length), "reply"))
        self.replies += 1
        return True

    def _maybe_speak(self, vocalization_start: int) -> None:
        """After a vocalization at room sample ``vocalization_start``, the robot may speak.

        Drawn from the speech stream only when ``robot_speech_probability`` > 0, so a
        room without robot speech sounds as before, sample for sample.
        """
        config = self.config
        if config.robot_speech_probability <= 0:
            return
        if self._speech_rng.random() >= config.robot_speech_probability:
            return
        first = vocalization_start + round(config.robot_speech_delay_s * self.rate)
        self._speak(first, self._speech_rng)

    def _chatter_gap(self) -> float:
        """Room samples to the robot's next utterance of its own (exponential; inf: none)."""
        rate_hz = self.config.robot_speech_rate_hz
        return math.inf if rate_hz <= 0 else self._chatter_rng.exponential(self.rate / rate_hz)

    def _speak(self, first: int, rng: np.random.Generator) -> None:
        """The robot says an utterance from room sample ``first`` on."""
        config = self.config
        length = rng.uniform(config.robot_speech_min_s, config.robot_speech_max_s)
        n = max(1, round(length * self.rate))
        voice = room_sounds.speech_like(n, self.rate, rng, config.syllable_rate_hz, self._robot_f0)
        self._sounds.append(_Sound(first, rms_scaled(voice, config.robot_speech_level_db),
                                   "robot_speech"))  # fmt: skip
        self._robot_speech.append((first, first + n))
        self.robot_utterances += 1

    def _reply(self, length_s: float) -> np.ndarray:
        """The partner's reply of ``length_s`` at ``reply_level_db`` (``reply_voice``)."""
        if self._partner_tts is not None:
            n = max(1, round(length_s * self.rate))
            voice = room_sounds.speech_excerpt(self._partner_tts, n, self.rate, self._reply_rng)
            return rms_scaled(voice, self.config.reply_level_db)
        if self._partner_f0 is not None:
            n = max(1, round(length_s * self.rate))
            voice = room_sounds.speech_like(
                n, self.rate, self._reply_rng, self.config.syllable_rate_hz, self._partner_f0
            )
            return rms_scaled(voice, self.config.reply_level_db)
        # noise: syllables of raised-cosine envelope, with short gaps
        n = max(1, round(length_s * self.rate))
        syllable = max(2, round(self.rate / self.config.syllable_rate_hz))
        t = np.arange(n) % syllable / syllable  # phase within the syllable, 0 .. 1
        envelope = np.where(t < 0.8, np.sin(np.pi * t / 0.8) ** 2, 0.0)
        loudness = self._reply_rng.uniform(0.6, 1.0, size=n // syllable + 1)
        envelope = envelope * np.repeat(loudness, syllable)[:n]
        return rms_scaled(self._reply_rng.standard_normal(n) * envelope, self.config.reply_level_db)

    def _event(self) -> np.ndarray:
        """A background event: a noise burst with a fast attack and exponential decay."""
        length = self._event_rng.uniform(self.config.event_min_s, self.config.event_max_s)
        n = max(1, round(length * self.rate))
        envelope = np.exp(-np.arange(n) / (n / 3.0))
        burst = self._event_rng.standard_normal(n) * envelope
        return rms_scaled(burst, self.config.event_level_db)

    def next_window(self) -> RoomWindow:
        """The sound of the next window."""
        start = self.windows_made * self.window
        end = start + self.window
        for stream in self._streams:
            self._sounds.extend(stream.due(end))
        while self._next_chatter < end:
            self._speak(int(self._next_chatter), self._chatter_rng)
            self._next_chatter += self._chatter_gap()
        x = self._floor.next(self.window)
        if self._meter is not None:
            self._measure("floor", x, self.window)
            for source in CONTINUOUS_SOURCES[1:]:  # continuous: every window counts
                if self._has(source):
                    self._measure(source, np.zeros(0), self.window)
        remaining = []
        for sound in self._sounds:
            sound_start, samples = sound.start, sound.samples
            lo, hi = max(start, sound_start), min(end, sound_start + samples.size)
            if lo < hi:
                part = samples[lo - sound_start : hi - sound_start]
                x[lo - start : hi - start] += part
                if self._meter is not None:
                    continuous = sound.source in CONTINUOUS_SOURCES
                    self._measure(sound.source, part, 0 if continuous else hi - lo)
            if sound_start + samples.size > end:
                remaining.append(sound)
        self._sounds = remaining
        robot_sound = any(first < end and start < last for first, last in self._robot_speech)
        self._robot_speech = [(first, last) for first, last in self._robot_speech if last > end]
        window = RoomWindow(
            index=self.windows_made,
            start_s=start / self.rate,
            samples=np.clip(x, -1.0, 1.0),
            partner_present=self.config.partner_present_at(start / self.rate),
            robot_sound=robot_sound,
        )
        self.windows_made += 1
        return window

    def _has(self, source: str) -> bool:
        """Does the room hold this continuous source."""
        config = self.config
        return {
            "babble": config.babble_talkers > 0,
            "tv": config.tv_on,
            "music": config.music_on,
            "hum": config.hum_on,
            "washer": config.washer_on,
        }[source]

    def _measure(self, source: str, part: np.ndarray, covered: int) -> None:
        """Add a part of a source's sound (its energy) and the samples it covers."""
        assert self._meter is not None
        totals = self._meter.setdefault(source, [0.0, 0.0])
        totals[0] += float(np.sum(part * part))
        totals[1] += covered

    def measured_levels_db(self) -> dict[str, float]:
        """Level of every source heard so far, dB FS (needs ``meter=True``).

        Transient sources: RMS over the samples their sounds covered (overlapping sounds
        of one source count twice); continuous sources (floor, babble, TV): RMS over all
        windows made.
        """
        if self._meter is None:
            raise ValueError("the room keeps no levels: make it with meter=True")
        return {
            source: 10.0 * math.log10(energy / samples) if energy > 0 else -math.inf
            for source, (energy, samples) in self._meter.items()
            if samples > 0
        }



def _poisson_sounds(
    room: FakeRoom,
    source: str,
    rng: np.random.Generator,
    rate_hz: float,
    level_db: float,
    make: Callable[[int, np.random.Generator], np.ndarray],
) -> _SoundStream:
    """Sounds ``make(rate, rng)`` at ``level_db`` (RMS over each), at Poisson times."""
    gap = room._poisson_gap(rng, rate_hz)

    def sound() -> list[tuple[int, np.ndarray]]:
        return [(0, rms_scaled(make(room.rate, rng), level_db))]

    return _SoundStream(source, gap, sound, gap)

def _newer_streams(
room: FakeRoom,
music: np.random.Generator,
traffic: np.random.Generator,
typing: np.random.Generator,
) -> list[_SoundStream]:
    """Music, the mains hum, traffic passing and typing (each only if the room has it)."""
    config, rate = room.config, room.rate
    streams = []
    if config.music_on:
        bar_samples = 4 * round(room_sounds.MUSIC_BEAT_S * rate)

        def bar() -> list[tuple[int, np.ndarray]]:
            return [(0, rms_scaled(room_sounds.music_bar(rate, music), config.music_level_db))]

        streams.append(
            _SoundStream(
                "music", lambda: -music.uniform(0.0, bar_samples), bar, lambda _: bar_samples
            )
        )
    if config.hum_on:
        block = rate  # 1 s: whole cycles of the hum
        gain = 10.0 ** (config.hum_level_db / 20.0) / math.sqrt(
            float(np.mean(room_sounds.mains_hum(block, rate, 0) ** 2))
        )
        position = [0]

        def hum() -> list[tuple[int, np.ndarray]]:
            samples = gain * room_sounds.mains_hum(block, rate, position[0])
            position[0] += block
            return [(0, samples)]

        streams.append(_SoundStream("hum", lambda: 0.0, hum, lambda _: block))
    for name, rng, rate_hz, level_db, make in (
        ("traffic", traffic, config.traffic_rate_hz, config.traffic_level_db,
         room_sounds.traffic_pass),
        ("typing", typing, config.typing_rate_hz, config.typing_level_db,
         room_sounds.typing_burst),
    ):  # fmt: skip
        if rate_hz > 0:
            streams.append(_poisson_sounds(room, name, rng, rate_hz, level_db, make))
    return streams


def as_transmitted(samples: np.ndarray) -> np.ndarray:
    """The samples as they travel on the ``audio`` topic: float32."""
    return np.asarray(samples, dtype=np.float32)
