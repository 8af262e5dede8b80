"""Latency of the robot's own sound: play it, find it on the microphone, derive the self period.

:func:`measure_latency` plays the sound through a
:class:`~infomax_contingency.audio.playback.SpeakerOutput` and finds its onset in a
:class:`~infomax_contingency.audio.capture.MicrophoneStream` recording
(:func:`find_onset`); :func:`self_period_windows` turns measured delays into the model's
self-feedback period. Times are seconds on the caller's clock (``time.monotonic()``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.capture import AudioChunk, MicrophoneStream
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError, check_positive
from infomax_contingency.audio.devices import AudioBackend, LogFunction, backend_or_default
from infomax_contingency.audio.playback import PlayEvent, SpeakerOutput
from infomax_contingency.audio.resample import resample


def find_onset(
    recording: ArrayLike, template: ArrayLike, min_score: float = 0.2
) -> tuple[int, float] | None:
    """Where a known sound starts in a recording (normalized cross-correlation).

    Args:
        recording: mono samples.
        template: the sound, mono, at the recording's rate (shorter than the recording).
        min_score: least normalized correlation (0..1) to accept.

    Returns:
        ``(index, score)``: the sample of ``recording`` where the template matches best
        and the normalized correlation there; None if the recording is too short or
        nothing matches with at least ``min_score``.
    """
    x = np.asarray(recording, dtype=np.float64)
    h = np.asarray(template, dtype=np.float64)
    n = h.size
    if n == 0 or x.size < n:
        return None
    from scipy.signal import correlate  # lazy: ~1 s of CPU to load

    raw = correlate(x, h, mode="valid", method="fft")
    c = np.concatenate(([0.0], np.cumsum(x * x)))
    local = np.sqrt(np.maximum(c[n:] - c[:-n], 0.0)) * math.sqrt(float(h @ h))
    score = np.divide(raw, local, out=np.zeros_like(raw), where=local > 1e-12)
    i = int(np.argmax(score))
    if score[i] < min_score:
        return None
    return i, float(score[i])


def self_period_windows(
    delay_min_s: float, delay_max_s: float, sound_s: float, window_s: float
) -> tuple[int, int]:
    """The self-feedback period ``(ts1, ts2)`` implied by a measured delay.

    Step convention (MODEL.md): the robot decides at the end of window t and its sound
    starts "at the start of the next step"; the window after the decision has timer
    ``z = 0``, the next ``z = 1``, and so on, window ``z`` covering
    ``[z * window_s, (z + 1) * window_s)`` seconds after the play command. The
    microphone hears the sound during ``[d, d + sound_s]``, with ``d`` the delay from the
    play command to the sound's onset at the microphone (output latency + flight + input
    latency). The self period is every window that overlaps that interval for any
    measured ``d`` in ``[delay_min_s, delay_max_s]``::

        ts1 = floor(delay_min_s / window_s)
        ts2 = ceil((delay_max_s + sound_s) / window_s) - 1

    Add room reverberation to ``sound_s`` when it is audible above the threshold.
    """
    if not 0 <= delay_min_s <= delay_max_s:
        raise AudioError(f"delays must satisfy 0 <= min <= max, got {delay_min_s}, {delay_max_s}")
    window_s = check_positive(window_s, "window_s")
    sound_s = check_positive(sound_s, "sound_s")
    ts1 = math.floor(delay_min_s / window_s + 1e-9)
    ts2 = math.ceil((delay_max_s + sound_s) / window_s - 1e-9) - 1
    return ts1, max(ts1, ts2)


@dataclasses.dataclass(frozen=True)
class LatencyTrial:
    """One play-and-listen measurement (times in seconds).

    Attributes:
        delay_s: from the play command to the sound's onset at the microphone.
        output_s: from the play command to the DAC start of the sound.
        score: normalized correlation of the match (0..1).
    """

    delay_s: float
    output_s: float
    score: float


@dataclasses.dataclass(frozen=True)
class LatencyReport:
    """Result of :func:`measure_latency`.

    Attributes:
        trials: the successful repeats.
        failures: one reason per repeat where the sound was not found.
        sound_s: length of the sound, seconds.
        input_device: microphone name.
        output_device: loudspeaker name.
    """

    trials: tuple[LatencyTrial, ...]
    failures: tuple[str, ...]
    sound_s: float
    input_device: str
    output_device: str

    @property
    def delays_s(self) -> NDArray[np.float64]:
        """The measured delays, seconds."""
        return np.array([t.delay_s for t in self.trials])


def measure_latency(
    input_device: int | str | None = None,
    output_device: int | str | None = None,
    repeats: int = 5,
    interval_s: float = 1.0,
    volume: float = 1.0,
    sound: str | Path | None = None,
    duration_s: float = 0.2,
    min_score: float = 0.2,
    log: LogFunction | None = None,
    backend: AudioBackend | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] | None = None,
) -> LatencyReport:
    """Play the robot's sound and find it on the microphone, ``repeats`` times.

    Each repeat plays the sound once and records ``interval_s`` seconds from the play
    command (make it longer than the delay plus the sound, or the sound is cut off). The
    onset is where the sound (resampled to the processing rate) correlates best with the
    recording (:func:`find_onset`). The delay runs from the play command to the onset,
    both on ``clock`` (ADC time of the recording, request time of the command);
    ``clock`` and ``sleep`` go to the speaker and the microphone (see
    :class:`~infomax_contingency.audio.capture.MicrophoneStream`).

    Raises:
        AudioDeviceError: a device is missing or unusable.
        AudioError: bad arguments.
    """
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise AudioError(f"repeats must be a positive integer, got {repeats!r}")
    interval_s = check_positive(interval_s, "interval_s")
    backend = backend_or_default(backend)
    rate = PROCESSING_RATE_HZ
    timing = {"log": log, "backend": backend, "clock": clock, "sleep": sleep}
    speaker = SpeakerOutput(
        output_device, sound=sound, duration_s=duration_s, volume=volume, **timing
    )
    mic = MicrophoneStream(input_device, window_s=0.1, queue_s=interval_s + 4.0, **timing)
    trials: list[LatencyTrial] = []
    failures: list[str] = []
    with speaker, mic:
        template = resample(speaker.sound, speaker.device_rate, rate)
        if interval_s <= template.size / rate:
            raise AudioError(
                f"interval_s ({interval_s} s) must be longer than the sound"
                f" ({template.size / rate:.3f} s)"
            )
        mic.read_audio(0.2)  # let the stream settle; drop what came so far
        for repeat in range(1, repeats + 1):
            trial = _one_repeat(speaker, mic, template, interval_s, min_score, repeat, clock)
            (failures if isinstance(trial, str) else trials).append(trial)
    return LatencyReport(
        tuple(trials),
        tuple(failures),
        template.size / rate,
        mic.status().device,
        speaker.status().device,
    )


def _one_repeat(
    speaker: SpeakerOutput,
    mic: MicrophoneStream,
    template: NDArray[np.float64],
    interval_s: float,
    min_score: float,
    repeat: int,
    clock: Callable[[], float],
) -> LatencyTrial | str:
    """Play once and record ``interval_s`` s: the trial, or the reason it failed."""
    rate = PROCESSING_RATE_HZ
    mic.read_audio(0.0)
    speaker.events(0.0)
    sequence = speaker.play()
    if sequence is None:
        return f"repeat {repeat}: the speaker is unavailable"
    chunks: list[AudioChunk] = []
    started: list[PlayEvent] = []
    deadline = clock() + interval_s + 2.0
    event = None
    while clock() < deadline:
        chunks.extend(mic.read_audio(0.05))
        started.extend(speaker.events(0.0))
        event = next((e for e in started if e.sequence == sequence), None)
        if event is not None and chunks and _covered(chunks, event, interval_s, rate):
            break
    return _analyse(chunks, event, template, rate, min_score, repeat)


def _covered(chunks: Sequence[AudioChunk], event: PlayEvent, interval_s: float, rate: int) -> bool:
    """True once the recording reaches ``interval_s`` after the play command."""
    last = chunks[-1]
    return last.start_time + last.samples.size / rate >= event.requested_time + interval_s


def _analyse(
    chunks: Sequence[AudioChunk],
    event: PlayEvent | None,
    template: NDArray[np.float64],
    rate: int,
    min_score: float,
    repeat: int,
) -> LatencyTrial | str:
    """One repeat's trial, or the reason it failed."""
    if event is None:
        return f"repeat {repeat}: the sound did not start"
    chunks = [c for c in chunks if c.segment == chunks[-1].segment] if chunks else []
    if not chunks:
        return f"repeat {repeat}: no audio from the microphone"
    if any(c.lost_samples or c.overflows for c in chunks[1:]):
        return f"repeat {repeat}: microphone audio was lost during the repeat (overflow)"
    x = np.concatenate([c.samples for c in chunks])
    t0 = chunks[0].start_time
    # only what was recorded after the command can be the sound
    first = max(0, math.floor((event.requested_time - t0) * rate))
    found = find_onset(x[first:], template, min_score)
    if found is None:
        return f"repeat {repeat}: the sound was not heard (raise the volume or move the microphone)"
    index, score = found
    onset = t0 + (first + index) / rate
    return LatencyTrial(
        delay_s=onset - event.requested_time,
        output_s=event.start_time - event.requested_time,
        score=score,
    )
