"""The sounds of a simulated room: noise floors, speech-like sound, events, a reverb tail.

Pure functions and small streaming filters on numpy arrays; every random draw comes from
a ``numpy.random.Generator`` the caller passes, so a room built on them is deterministic
from its seed. :class:`~infomax_contingency.sim.fake_room.FakeRoom` schedules them.

Conventions: samples are float64, mono, at ``rate`` Hz; a function that returns a sound
at a level returns it scaled so that its RMS over its whole length is ``level_db`` dB
relative to full scale (:func:`rms_scaled`); the others return sound of arbitrary scale.

Spectra of the noise floors (:data:`FLOOR_SPECTRA`), as power per octave:

* ``white`` — flat (the same power per Hz: +3 dB per octave);
* ``pink`` — 1/f, the same power in every octave (-3 dB per octave in power per Hz),
  from Paul Kellet's three-pole filter; within about 1 dB of 1/f from 20 Hz to 6 kHz at
  16 kHz;
* ``hvac`` — 1/f^2 above 13 Hz (-6 dB per octave in power per Hz: a one-pole leaky
  integrator with pole 0.995 at 16 kHz), the low rumble of ventilation.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

FLOOR_SPECTRA = ("white", "pink", "hvac")
"""The noise floor spectra (see the module docstring)."""

_PINK_B = np.array([0.049922035, -0.095993537, 0.050612699, -0.004408786])
_PINK_A = np.array([1.0, -2.494956002, 2.017265875, -0.522189400])
_HVAC_POLE = 0.995
_WARM_UP_SAMPLES = 8192
"""Samples a coloured floor filter runs before its first output (its state settles)."""


def rms_scaled(x: NDArray[np.float64], level_db: float) -> NDArray[np.float64]:
    """``x`` scaled to an RMS of ``level_db`` dB full scale (all-zero ``x`` is returned as is)."""
    rms = math.sqrt(float(np.mean(x * x))) if x.size else 0.0
    return x * (10.0 ** (level_db / 20.0) / rms) if rms > 0 else x


def level_db(x: NDArray[np.float64]) -> float:
    """RMS level of ``x`` in dB full scale (``-inf`` for silence)."""
    mean_square = float(np.mean(x * x)) if x.size else 0.0
    return 10.0 * math.log10(mean_square) if mean_square > 0 else -math.inf


class NoiseFloor:
    """A streaming noise floor of a given spectrum at an RMS level.

    Consecutive calls of :meth:`next` continue one signal (the filter state is kept).
    The ``white`` floor is ``rng.standard_normal(n) * 10 ** (level_db / 20)``, exactly.

    Args:
        spectrum: one of :data:`FLOOR_SPECTRA`.
        level_db: long-term RMS, dB full scale.
        rng: the floor's random stream.
    """

    def __init__(self, spectrum: str, level_db: float, rng: np.random.Generator) -> None:
        if spectrum not in FLOOR_SPECTRA:
            raise ValueError(f"noise floor spectrum {spectrum!r}: must be one of {FLOOR_SPECTRA}")
        self.spectrum = spectrum
        self.rng = rng
        self.rms = 10.0 ** (level_db / 20.0)
        self._state: NDArray[np.float64] | None = None
        if spectrum == "white":  # no filter: neither scipy.signal (about 1 s of CPU to load)
            return
        if spectrum == "pink":
            self._b, self._a = _PINK_B, _PINK_A
        else:
            self._b, self._a = np.array([1.0 - _HVAC_POLE]), np.array([1.0, -_HVAC_POLE])
        from scipy.signal import lfilter, lfilter_zi  # lazy: only coloured floors filter

        impulse = np.zeros(1 << 16)
        impulse[0] = 1.0
        response = lfilter(self._b, self._a, impulse)
        self._gain = 1.0 / math.sqrt(float(np.sum(response * response)))
        self._state = lfilter_zi(self._b, self._a) * 0.0
        self.next(_WARM_UP_SAMPLES)

    def next(self, n: int) -> NDArray[np.float64]:
        """The next ``n`` samples."""
        x = self.rng.standard_normal(n)
        if self._state is None or n == 0:  # lfilter of no samples returns a wrong state
            return x * self.rms
        from scipy.signal import lfilter

        y, self._state = lfilter(self._b, self._a, x, zi=self._state)
        return y * (self._gain * self.rms)


@functools.lru_cache(maxsize=64)
def _butterworth(band: float | tuple[float, float], rate: int) -> tuple[NDArray, NDArray]:
    """Second-order Butterworth coefficients: a low-pass at ``band`` Hz, or a band-pass."""
    from scipy.signal import butter

    return butter(2, band, btype="lowpass" if isinstance(band, float) else "bandpass", fs=rate)


def lowpass(x: NDArray[np.float64], cutoff_hz: float, rate: int) -> NDArray[np.float64]:
    """Second-order Butterworth low-pass at ``cutoff_hz`` (sound heard from a distance).

    A cutoff at or above half the rate passes ``x`` as it is.
    """
    if cutoff_hz >= rate / 2:
        return x
    from scipy.signal import lfilter

    return lfilter(*_butterworth(float(cutoff_hz), rate), x)


def bandpass(x: NDArray[np.float64], low_hz: float, high_hz: float, rate: int) -> NDArray:
    """Second-order Butterworth band-pass from ``low_hz`` to ``high_hz``.

    The upper edge is kept below 0.45 of the rate; a band that leaves nothing then (a rate
    too low for it) is a low-pass at ``low_hz``, as :func:`lowpass`.
    """
    high = min(high_hz, 0.45 * rate)
    if not low_hz < high:
        return lowpass(x, low_hz, rate)
    from scipy.signal import lfilter

    return lfilter(*_butterworth((float(low_hz), float(high)), rate), x)


def resonator(x: NDArray[np.float64], freq_hz: float, bandwidth_hz: float, rate: int) -> NDArray:
    """A two-pole resonance (a formant) at ``freq_hz`` of ``bandwidth_hz``."""
    from scipy.signal import lfilter

    r = math.exp(-math.pi * bandwidth_hz / rate)
    a = [1.0, -2.0 * r * math.cos(2.0 * math.pi * freq_hz / rate), r * r]
    return lfilter([1.0 - r], a, x)


def syllable_envelope(n: int, rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """One syllable's loudness: a 10-30 ms rise, a sustain, a decay over its last 40 %."""
    attack = min(n // 3, max(1, round(rng.uniform(0.01, 0.03) * rate)))
    decay = max(1, round(0.4 * n))
    env = np.ones(n)
    env[:attack] = np.sin(0.5 * np.pi * (np.arange(attack) + 0.5) / attack) ** 2
    fall = min(decay, n - attack)
    if fall > 0:
        env[n - fall :] = np.cos(0.5 * np.pi * (np.arange(fall) + 0.5) / fall) ** 2
    return env


def speech_like(
    n: int,
    rate: int,
    rng: np.random.Generator,
    syllable_rate_hz: float = 4.0,
    f0_hz: float | None = None,
) -> NDArray[np.float64]:
    """``n`` samples of speech-like sound (arbitrary scale).

    Syllables of ``1 / syllable_rate_hz`` (x 0.6 .. 1.4) with a 10-30 ms onset and a
    decay; each one voiced: a pulse train at the pitch ``f0_hz`` (drawn in 100 .. 250 Hz
    when None; +-8 % per syllable, falling 10 % over it) with 10 % breath noise, shaped by
    two formants drawn per syllable (F1 300 .. 800 Hz, F2 900 .. 2300 Hz), loudness
    0.5 .. 1 per syllable; a pause of 40 .. 150 ms after one syllable in five.
    """
    out = np.zeros(n)
    pitch = rng.uniform(100.0, 250.0) if f0_hz is None else f0_hz
    position = 0
    mean_syllable = rate / syllable_rate_hz
    while position < n:
        length = min(n - position, max(8, round(mean_syllable * rng.uniform(0.6, 1.4))))
        f0 = pitch * rng.uniform(0.92, 1.08) * np.linspace(1.0, 0.9, length)
        phase = np.cumsum(f0 / rate) % 1.0
        source = (2.0 * phase - 1.0) + 0.1 * rng.standard_normal(length)
        voiced = resonator(source, rng.uniform(300.0, 800.0), 90.0, rate)
        voiced = voiced + 0.7 * resonator(source, rng.uniform(900.0, 2300.0), 120.0, rate)
        envelope = syllable_envelope(length, rate, rng) * rng.uniform(0.5, 1.0)
        out[position : position + length] = voiced * envelope
        position += length
        if rng.random() < 0.2:
            position += round(rng.uniform(0.04, 0.15) * rate)
    return out


def door_slam(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A door slam, 0.3 .. 0.6 s: a low thump (60 .. 120 Hz) and a low-passed crack, decaying."""
    n = round(rng.uniform(0.3, 0.6) * rate)
    t = np.arange(n) / rate
    decay = np.exp(-t / (n / rate / 5.0))
    thump = np.sin(2.0 * np.pi * rng.uniform(60.0, 120.0) * t)
    crack = lowpass(rng.standard_normal(n), 2500.0, rate)
    crack /= max(1e-12, float(np.std(crack)))
    return (thump + 0.8 * crack) * decay


def footstep(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """One footstep, 40 .. 80 ms: a low-passed click with a fast decay."""
    n = round(rng.uniform(0.04, 0.08) * rate)
    burst = lowpass(rng.standard_normal(n), 800.0, rate)
    return burst * np.exp(-np.arange(n) / (n / 4.0))


def reverb_tail(
    dry: NDArray[np.float64], rt60_s: float, rate: int, rng: np.random.Generator
) -> NDArray[np.float64]:
    """The room's echo of ``dry``: ``dry`` convolved with decaying noise (arbitrary scale).

    The impulse response is white noise under an exponential envelope that falls 60 dB
    in ``rt60_s`` seconds, starting 10 ms after the direct sound (the first reflection),
    low-passed at 4 kHz (walls absorb the highs); the tail is ``dry.size +
    round((rt60_s + 0.01) * rate)`` samples long and starts with the direct sound.
    """
    length = max(1, round(rt60_s * rate))
    pre = round(0.01 * rate)
    envelope = np.exp(-6.907755 * np.arange(length) / length)  # -60 dB at rt60
    response = np.concatenate([np.zeros(pre), lowpass(rng.standard_normal(length), 4000.0, rate)])
    response[pre:] *= envelope
    return np.convolve(dry, response)


SPEECH_BANK_VOICES_HZ = (110.0, 140.0, 190.0, 230.0)
"""Pitches of the voices of the speech bank, Hz."""
SPEECH_BANK_S = 20.0
"""Length of each voice of the speech bank, seconds."""
SPEECH_BANK_SEED = 2010
"""Seed of the speech bank (the same bank in every room; rooms draw excerpts of it)."""
_EXCERPT_FADE_S = 0.02


@functools.lru_cache(maxsize=8)
def speech_bank(
    rate: int, syllable_rate_hz: float, cutoff_hz: float
) -> tuple[NDArray[np.float64], ...]:
    """Speech-like sound of every voice of :data:`SPEECH_BANK_VOICES_HZ`, low-passed, unit RMS.

    Made once per process and argument set from :data:`SPEECH_BANK_SEED`; background
    talkers and the TV play excerpts of it (:func:`speech_excerpt`), which costs far less
    than making new speech for every utterance. The arrays are read-only.
    """
    rng = np.random.default_rng(SPEECH_BANK_SEED)
    n = round(SPEECH_BANK_S * rate)
    voices = []
    for f0 in SPEECH_BANK_VOICES_HZ:
        voice = rms_scaled(
            lowpass(speech_like(n, rate, rng, syllable_rate_hz, f0), cutoff_hz, rate), 0.0
        )
        voice.setflags(write=False)
        voices.append(voice)
    return tuple(voices)


def speech_excerpt(
    voice: NDArray[np.float64], n: int, rate: int, rng: np.random.Generator
) -> NDArray[np.float64]:
    """``n`` samples of ``voice`` from a random offset, faded in and out over 20 ms.

    ``n`` longer than the voice repeats it (from a random offset).
    """
    offset = int(rng.integers(0, voice.size))
    if offset + n <= voice.size:
        x = voice[offset : offset + n].copy()
    else:
        x = voice[(offset + np.arange(n)) % voice.size]
    fade = min(round(_EXCERPT_FADE_S * rate), n // 2)
    if fade > 0:
        ramp = np.sin(0.5 * np.pi * (np.arange(fade) + 0.5) / fade) ** 2
        x[:fade] *= ramp
        x[n - fade :] *= ramp[::-1]
    return x


# ---------------------------------------------------------------- sources of the newer rooms


@functools.lru_cache(maxsize=8)
def tts_voices(rate: int, cutoff_hz: float) -> tuple[NDArray[np.float64], ...]:
    """The espeak-ng speech bank (:func:`~infomax_contingency.sim.tts.tts_bank`), low-passed.

    ``cutoff_hz`` at or above half the rate: as spoken. Unit RMS, read-only.
    """
    from infomax_contingency.sim.tts import tts_bank

    voices = []
    for voice in tts_bank(rate):
        x = rms_scaled(lowpass(np.asarray(voice), cutoff_hz, rate), 0.0)
        x.setflags(write=False)
        voices.append(x)
    return tuple(voices)


MUSIC_BEAT_S = 0.5
"""Length of a beat of :func:`music_bar`, seconds (120 beats per minute)."""
_MUSIC_CHORDS_HZ = (
    (220.0, 277.2, 329.6),  # A major
    (196.0, 246.9, 293.7),  # G major
    (174.6, 220.0, 261.6),  # F major
    (164.8, 207.7, 246.9),  # E major
)


def music_bar(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """Four beats of pop music (arbitrary scale): a chord, a bass line and a hi-hat.

    Each beat of :data:`MUSIC_BEAT_S`: the bar's chord (one of four, three tones with
    four harmonics each, decaying over the beat), the chord's root an octave down on
    beats 1 and 3, and a hi-hat (a 30 ms burst of high-passed noise) on every half beat.
    """
    beat = round(MUSIC_BEAT_S * rate)
    n = 4 * beat
    t = np.arange(beat) / rate
    chord = _MUSIC_CHORDS_HZ[int(rng.integers(len(_MUSIC_CHORDS_HZ)))]
    out = np.zeros(n)
    decay = np.exp(-t / 0.35)
    for k in range(4):
        tone = np.zeros(beat)
        for f in chord:
            for h in range(1, 5):
                tone += np.sin(2 * np.pi * f * h * t + rng.uniform(0, 2 * np.pi)) / h**1.5
        tone *= decay * rng.uniform(0.7, 1.0)
        if k % 2 == 0:
            tone += 1.5 * np.sin(2 * np.pi * chord[0] / 2 * t) * np.exp(-t / 0.25)
        out[k * beat : (k + 1) * beat] += tone
    hat = round(0.03 * rate)
    for k in range(8):
        burst = np.diff(rng.standard_normal(hat + 1)) * np.exp(-np.arange(hat) / (hat / 5))
        start = k * beat // 2
        out[start : start + hat] += 0.8 * burst
    return out


def traffic_pass(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A vehicle passing, 3 .. 8 s: low-passed noise under a swell (arbitrary scale).

    Noise low-passed at 300 .. 800 Hz (tyres and engine from a distance), its loudness a
    raised cosine over the pass: it swells, peaks half-way and fades.
    """
    n = round(rng.uniform(3.0, 8.0) * rate)
    noise = lowpass(rng.standard_normal(n), rng.uniform(300.0, 800.0), rate)
    swell = np.sin(np.pi * (np.arange(n) + 0.5) / n) ** 4
    return noise * swell


HUM_HZ = 50.0
"""Fundamental of :func:`mains_hum`, Hz (mains frequency)."""


def mains_hum(n: int, rate: int, start: int) -> NDArray[np.float64]:
    """Samples ``start .. start + n`` of a steady hum: 50 Hz and harmonics (arbitrary scale).

    Harmonics 1-6 of :data:`HUM_HZ` at 1/k of the fundamental's amplitude (a fridge, a
    ventilation motor); deterministic and continuous across calls.
    """
    t = (start + np.arange(n)) / rate
    return sum(np.sin(2 * np.pi * HUM_HZ * k * t + 0.7 * k) / k for k in range(1, 7))


def typing_burst(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """Someone typing for 2 .. 8 s: key clicks 6 .. 10 per second (arbitrary scale).

    Each click: 4 .. 10 ms of differentiated (high-passed) noise with a fast decay,
    loudness 0.5 .. 1 (a space bar now and then twice as loud).
    """
    n = round(rng.uniform(2.0, 8.0) * rate)
    out = np.zeros(n)
    position = 0
    rate_keys = rng.uniform(6.0, 10.0)
    while position < n:
        length = round(rng.uniform(0.004, 0.010) * rate)
        click = np.diff(rng.standard_normal(length + 1)) * np.exp(-np.arange(length) / (length / 4))
        gain = rng.uniform(0.5, 1.0) * (2.0 if rng.random() < 0.1 else 1.0)
        end = min(n, position + length)
        out[position:end] += gain * click[: end - position]
        position += max(1, round(rng.exponential(1.0 / rate_keys) * rate))
    return out


def voice_bank(
    voice: str, rate: int, syllable_rate_hz: float, cutoff_hz: float
) -> tuple[NDArray[np.float64], ...]:
    """The voices distant talkers or a TV speak with, low-passed at ``cutoff_hz``.

    ``voice``: ``synthetic`` (:func:`speech_bank`) or ``tts`` (:func:`tts_voices`).
    """
    if voice == "tts":
        return tts_voices(rate, cutoff_hz)
    return speech_bank(rate, syllable_rate_hz, cutoff_hz)
