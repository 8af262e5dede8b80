"""The sounds of the later held-out rooms: toys, a dog, a washing machine, a vacuum cleaner.

Pure functions on numpy arrays, as :mod:`infomax_contingency.sim.room_sounds`: every random
draw comes from the ``numpy.random.Generator`` the caller passes, and every sound is of
arbitrary scale (the caller scales it to its level with
:func:`~infomax_contingency.sim.room_sounds.rms_scaled`). The children's voices of the
``playroom`` are espeak-ng's (:func:`~infomax_contingency.sim.tts.children_bank`); when
these sounds play is :mod:`infomax_contingency.sim.household_streams`.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.sim.room_sounds import bandpass, lowpass, resonator


def _harmonics(phase: NDArray[np.float64]) -> NDArray[np.float64]:
    """``sin(phase) + sin(2 phase) / 2 + sin(3 phase) / 3`` (two trigonometric calls)."""
    s1, c1 = np.sin(phase), np.cos(phase)
    return s1 * (1.0 + c1 + (3.0 - 4.0 * s1 * s1) / 3.0)


def _ramp(n: int) -> NDArray[np.float64]:
    """A raised-cosine rise over ``n`` samples, 0 .. 1."""
    return np.sin(0.5 * np.pi * (np.arange(n) + 0.5) / max(1, n)) ** 2


# ------------------------------------------------------------------------- the playroom


def toy_squeak(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A squeeze toy, 0.12 .. 0.35 s: a whistle of 1.5 .. 3.5 kHz gliding up then down.

    The tone (its second harmonic at 0.3) glides +-15 % with a 25-35 Hz flutter, over
    high-passed breath noise at 0.15; a 10 ms attack and a 30 ms release.
    """
    n = round(rng.uniform(0.12, 0.35) * rate)
    u = np.arange(n) / n
    flutter = 1.0 + 0.03 * np.sin(2 * np.pi * rng.uniform(25.0, 35.0) * np.arange(n) / rate)
    f = rng.uniform(1500.0, 3500.0) * (0.85 + 0.3 * np.sin(np.pi * u)) * flutter
    phase = 2 * np.pi * np.cumsum(f) / rate
    breath = np.diff(rng.standard_normal(n + 1)) / np.sqrt(2)  # high-passed
    tone = np.sin(phase) + 0.3 * np.sin(2 * phase) + 0.15 * breath
    envelope = np.ones(n)
    attack, release = round(0.01 * rate), round(0.03 * rate)
    envelope[:attack] = _ramp(attack)
    envelope[n - release :] = _ramp(release)[::-1]
    return tone * envelope


def toy_rattle(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A rattle shaken, 0.3 .. 0.8 s: beads hitting, clicks of 2-6 kHz in shakes of 4-7 Hz.

    Each shake (half a period) throws 2 .. 5 clicks of 2 .. 5 ms, 0 .. 25 ms after its
    start, loudness 0.4 .. 1.
    """
    n = round(rng.uniform(0.3, 0.8) * rate)
    out = np.zeros(n)
    half_period = rate / rng.uniform(4.0, 7.0) / 2
    shake = 0.0
    while shake < n:
        for _ in range(int(rng.integers(2, 6))):
            length = round(rng.uniform(0.002, 0.005) * rate)
            start = round(shake + rng.uniform(0.0, 0.025) * rate)
            click = rng.standard_normal(length) * np.exp(-np.arange(length) / (length / 4))
            end = min(n, start + length)
            if start < end:
                out[start:end] += rng.uniform(0.4, 1.0) * click[: end - start]
        shake += half_period
    return bandpass(out, 2000.0, 6000.0, rate)


def toy_sound(rate: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A toy: a squeak (:func:`toy_squeak`, 60 %) or a rattle (:func:`toy_rattle`)."""
    return toy_squeak(rate, rng) if rng.random() < 0.6 else toy_rattle(rate, rng)


# ------------------------------------------------------------------------------- the dog


def dog_bark(rate: int, rng: np.random.Generator, f0_hz: float) -> NDArray[np.float64]:
    """One bark, 0.1 .. 0.3 s, of a dog whose voice is at ``f0_hz`` (400 .. 800 Hz).

    Harmonics of a fundamental (``f0_hz`` x 0.9 .. 1.1) that rises 12.5 % by mid-bark and
    ends 20 % below its start, at 1/k, with harsh noise at half their RMS; two formants
    (F1 800 .. 1200 Hz, F2 1800 .. 2800 Hz) over a third of the raw sound; a 5-15 ms
    attack and a decay to a tenth at the end.
    """
    n = round(rng.uniform(0.1, 0.3) * rate)
    u = np.arange(n) / n
    f = f0_hz * rng.uniform(0.9, 1.1) * (1.0 + 0.25 * np.sin(np.pi * u)) * (1.0 - 0.2 * u)
    phase = 2 * np.pi * np.cumsum(f) / rate
    voiced = np.zeros(n)
    for k in range(1, int(0.45 * rate / (1.3 * f0_hz)) + 1):
        voiced += np.sin(k * phase + rng.uniform(0, 2 * np.pi)) / k
    source = voiced + 0.5 * float(np.std(voiced)) * rng.standard_normal(n)
    shaped = resonator(source, rng.uniform(800.0, 1200.0), 250.0, rate) + 0.6 * resonator(
        source, rng.uniform(1800.0, 2800.0), 350.0, rate
    )
    shaped = shaped / max(1e-12, float(np.std(shaped)))
    shaped = shaped + source / max(1e-12, 3 * float(np.std(source)))  # none at a rate too low
    envelope = np.exp(-np.log(10.0) * u)
    attack = round(rng.uniform(0.005, 0.015) * rate)
    envelope[:attack] *= _ramp(attack)
    return shaped * envelope


# ------------------------------------------------------------------ the washing machine


@functools.lru_cache(maxsize=8)
def _motor_second(rate: int, motor_hz: int) -> NDArray[np.float64]:
    """One second of the washer motor's whine: ``motor_hz`` and harmonics 2-4 at 1/k.

    A whole number of Hz: the whine repeats every second. Read-only.
    """
    t = np.arange(rate) / rate
    motor = sum(np.sin(2 * np.pi * motor_hz * k * t + 0.9 * k) / k for k in range(1, 5))
    motor.setflags(write=False)
    return motor


def washer_turn(
    n: int, rate: int, rng: np.random.Generator, motor_hz: float, start: int
) -> NDArray[np.float64]:
    """One turn of a washing machine's drum, ``n`` samples from room sample ``start``.

    The motor's whine (``motor_hz`` rounded to whole Hz, and harmonics 2-4 at 1/k; its
    phase continuous across turns: the sample index ``start`` sets it) pulled 15 % louder
    as the load rises; water sloshing (noise low-passed at 600 Hz) that swells mid-turn,
    and the load falling (a thump of 45 .. 80 Hz with a 40 ms decay and a low-passed
    crack, 0.3 s) at 0.55 .. 0.75 of the turn. Both swell and thump are quiet at the
    turn's ends, so turns join smoothly.
    """
    rise = np.sin(np.pi * np.arange(n) / n)
    motor = _motor_second(rate, round(motor_hz))[(start + np.arange(n)) % rate]
    slosh = lowpass(rng.standard_normal(n), 600.0, rate) * (rise * rise)
    out = 0.35 * motor * (1.0 + 0.15 * rise) + 2.0 * slosh / max(1e-12, float(np.std(slosh)))
    fall = round(rng.uniform(0.55, 0.75) * n)
    tail = np.arange(min(n - fall, round(0.3 * rate))) / rate
    out[fall : fall + tail.size] += (1.5 * np.exp(-tail / 0.04)) * (
        np.sin(2 * np.pi * rng.uniform(45.0, 80.0) * tail)
        + 0.3 * lowpass(rng.standard_normal(tail.size), 1500.0, rate)
    )
    return out


def spin_cycle(rate: int, rng: np.random.Generator, motor_hz: float) -> NDArray[np.float64]:
    """A spin, 6 .. 12 s: the whine climbs from 2x to 5 .. 7x ``motor_hz``, then holds.

    The whine (harmonics 1-3 at 1/k) rises over the first 60 % (exponentially toward its
    top speed) under a rush of air and water (noise band-passed 250 .. 2500 Hz) that grows
    with the speed; it swells in over 2 s and dies away over its last 1 s.
    """
    n = round(rng.uniform(6.0, 12.0) * rate)
    u = np.arange(n) / n
    speed = 1.0 - np.exp(-u / 0.2)  # 0 .. 0.99: the drum spins up
    f = motor_hz * (2.0 + rng.uniform(3.0, 5.0) * speed)
    phase = 2 * np.pi * np.cumsum(f) / rate
    whine = _harmonics(phase)
    rush = bandpass(rng.standard_normal(n), 250.0, 2500.0, rate)
    rush *= (0.3 + 0.7 * speed) / max(1e-12, float(np.std(rush)))
    envelope = np.ones(n)
    rise, fade = round(2.0 * rate), round(1.0 * rate)
    envelope[:rise] = _ramp(rise)
    envelope[n - fade :] = _ramp(fade)[::-1]
    return (0.6 * whine + rush) * envelope


# --------------------------------------------------------------- the vacuum next door


VACUUM_ON_S = (5.0, 25.0)
"""Shortest and longest run of the vacuum cleaner, seconds (uniform)."""


def vacuum_run(rate: int, rng: np.random.Generator, motor_hz: float) -> NDArray[np.float64]:
    """A vacuum cleaner in the next room running for 5 .. 25 s (heard through the wall).

    Broadband noise band-passed from 120 Hz to 1.2 .. 2 kHz (the wall takes the highs)
    and the motor's tone (``motor_hz``, harmonics 1-3); it spins up (the motor from half
    speed) and down over 0.3 s at each end, and the nozzle pushed back and forth makes it
    20 % louder and softer at 0.4 .. 0.8 Hz.
    """
    n = round(rng.uniform(*VACUUM_ON_S) * rate)
    edge = round(0.3 * rate)
    gain = np.ones(n)
    gain[:edge] = _ramp(edge)
    gain[n - edge :] = _ramp(edge)[::-1]
    f = motor_hz * (0.5 + 0.5 * gain)
    phase = 2 * np.pi * np.cumsum(f) / rate
    tone = _harmonics(phase)
    noise = bandpass(rng.standard_normal(n), 120.0, rng.uniform(1200.0, 2000.0), rate)
    noise /= max(1e-12, float(np.std(noise)))
    strokes = 1.0 + 0.2 * np.sin(
        2 * np.pi * rng.uniform(0.4, 0.8) * np.arange(n) / rate + rng.uniform(0, 2 * np.pi)
    )
    return (noise + 0.5 * tone) * gain * strokes
