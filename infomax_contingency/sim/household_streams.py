"""When the later held-out rooms' sources sound: children, toys, a dog, a washer, a vacuum.

:class:`~infomax_contingency.sim.fake_room.FakeRoom` plays each source of
:data:`HOUSEHOLD_SOURCES` the room has (see
:class:`~infomax_contingency.sim.room_config.FakeRoomConfig`) from a random stream of its
own, spawned after the first rooms' streams, so a room without them sounds as before,
sample for sample. Each source is described here as a stream
(:data:`StreamSpec`: its name, the first sound's start, the next sound's parts, the gap to
the one after); the sounds are :mod:`infomax_contingency.sim.household_sounds` and the
children's espeak-ng voices (:func:`~infomax_contingency.sim.tts.children_bank`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.sim import household_sounds
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.sim.room_sounds import rms_scaled, speech_excerpt

Part = tuple[int, NDArray[np.float64]]
"""A part of a sound: (offset from the sound's start in samples, samples)."""
StreamSpec = tuple[
    str, Callable[[], float], Callable[[], list[Part]], Callable[[list[Part]], float]
]
"""A source as a stream: (source name, first start, next sound's parts, gap to the next)."""

HOUSEHOLD_SOURCES = ("children", "toy", "bark", "washer", "spin", "vacuum")
"""The sources of the later rooms, in the order of their random streams."""

CHILD_BURST_S = (0.4, 2.5)
"""Shortest and longest burst of a child's talking or shouting, seconds (uniform)."""
CHILD_PAUSE_MEAN_S = 2.5
"""Mean pause between a child's bursts, seconds (exponential)."""
CHILD_SPREAD_DB = 4.0
"""A burst is ``children_level_db`` +- this (uniform; the loud ones are shouts), the mean
energy kept at ``children_level_db``."""
BARKS_PER_CLUSTER = (1, 5)
"""Fewest and most barks of a cluster."""
BARK_GAP_S = (0.2, 0.6)
"""Shortest and longest silence between two barks of a cluster, seconds (uniform)."""
DOG_F0_HZ = (400.0, 800.0)
"""Range of the dog's voice (its fundamental, drawn once per room), Hz."""
BARK_CLUSTER_GAP_FACTOR = (0.75, 1.25)
"""Time from a cluster of barks to the next, times ``1 / bark_rate_hz`` (uniform)."""
WASHER_TURN_S = (1.0 / 1.2, 1.0 / 0.8)
"""Time of one turn of the drum (drawn once per room, +-4 % per turn), seconds."""
WASHER_MOTOR_HZ = (120.0, 200.0)
"""Range of the washer motor's whine during the wash (drawn once per room), Hz."""
SPIN_EVERY_S = (20.0, 30.0)
"""Time from one spin's start to the next one's, seconds (uniform)."""
VACUUM_OFF_S = (5.0, 20.0)
"""Shortest and longest time the vacuum cleaner is off, seconds (uniform)."""
VACUUM_MOTOR_HZ = (250.0, 350.0)
"""Range of the vacuum motor's tone (drawn once per room), Hz."""


def household_streams(
    config: FakeRoomConfig, rate: int, seeds: Sequence[np.random.SeedSequence]
) -> list[StreamSpec]:
    """The streams of the sources of :data:`HOUSEHOLD_SOURCES` the room has, but the toys.

    ``seeds``: one per source, in that order; a source the room lacks draws nothing. The
    toys sound at Poisson times, as the knocks: FakeRoom schedules them itself.
    """
    rngs = dict(zip(HOUSEHOLD_SOURCES, seeds, strict=True))
    streams = []
    if config.children_talkers > 0:
        streams += _children(config, rate, np.random.default_rng(rngs["children"]))
    if config.bark_rate_hz > 0:
        streams.append(_dog(config, rate, np.random.default_rng(rngs["bark"])))
    if config.washer_on:
        washer, spin = (np.random.default_rng(rngs[name]) for name in ("washer", "spin"))
        streams += _washer(config, rate, washer, spin)
    if config.vacuum_on:
        streams.append(_vacuum(config, rate, np.random.default_rng(rngs["vacuum"])))
    return streams


def _children(config: FakeRoomConfig, rate: int, rng: np.random.Generator) -> list[StreamSpec]:
    """Each child: bursts of :data:`CHILD_BURST_S` with exponential pauses, a voice of its own.

    The children take the voices of the bank in a random order (more children than
    voices: again from the first).
    """
    from infomax_contingency.sim.tts import children_bank

    bank = children_bank(rate)
    order = rng.permutation(len(bank))
    spread = CHILD_SPREAD_DB
    # the mean of 10^(x/10) for x uniform in +-spread, in dB: taken off, the mean energy stays
    mean_gain = (10 ** (spread / 10) - 10 ** (-spread / 10)) / (0.2 * spread * math.log(10))
    mean_db = 10 * math.log10(mean_gain)
    low, high = CHILD_BURST_S
    cycle = (0.5 * (low + high) + CHILD_PAUSE_MEAN_S) * rate
    streams: list[StreamSpec] = []
    for k in range(config.children_talkers):
        child = np.random.default_rng(rng.integers(2**63))
        voice = bank[int(order[k % len(bank)])]

        def burst(child: np.random.Generator = child, voice: NDArray = voice) -> list[Part]:
            n = max(1, round(child.uniform(low, high) * rate))
            level = config.children_level_db - mean_db + child.uniform(-spread, spread)
            return [(0, rms_scaled(speech_excerpt(voice, n, rate, child), level))]

        def gap(parts: list[Part], child: np.random.Generator = child) -> float:
            return parts[0][1].size + child.exponential(CHILD_PAUSE_MEAN_S * rate)

        first = -child.uniform(0.0, cycle)
        streams.append(("children", lambda first=first: first, burst, gap))
    return streams


def _dog(config: FakeRoomConfig, rate: int, rng: np.random.Generator) -> StreamSpec:
    """Clusters of :data:`BARKS_PER_CLUSTER` barks, :data:`BARK_CLUSTER_GAP_FACTOR` / rate apart."""
    f0 = rng.uniform(*DOG_F0_HZ)
    spacing = rate / config.bark_rate_hz

    def cluster() -> list[Part]:
        parts: list[Part] = []
        position = 0
        for _ in range(int(rng.integers(BARKS_PER_CLUSTER[0], BARKS_PER_CLUSTER[1] + 1))):
            bark = rms_scaled(household_sounds.dog_bark(rate, rng, f0), config.bark_level_db)
            parts.append((position, bark))
            position += bark.size + round(rng.uniform(*BARK_GAP_S) * rate)
        return parts

    def gap(_: list[Part]) -> float:
        return rng.uniform(*BARK_CLUSTER_GAP_FACTOR) * spacing

    return ("bark", lambda: rng.uniform(0.0, spacing), cluster, gap)


def _washer(
    config: FakeRoomConfig, rate: int, rng: np.random.Generator, spin_rng: np.random.Generator
) -> list[StreamSpec]:
    """The wash (turn after turn at ``washer_level_db``) and a spin every :data:`SPIN_EVERY_S`."""
    motor_hz = rng.uniform(*WASHER_MOTOR_HZ)
    turn_s = rng.uniform(*WASHER_TURN_S)
    position = [0]

    def turn() -> list[Part]:
        n = round(turn_s * rng.uniform(0.96, 1.04) * rate)
        samples = household_sounds.washer_turn(n, rate, rng, motor_hz, position[0])
        position[0] += n
        return [(0, rms_scaled(samples, config.washer_level_db))]

    def spin() -> list[Part]:
        samples = household_sounds.spin_cycle(rate, spin_rng, motor_hz)
        return [(0, rms_scaled(samples, config.washer_spin_level_db))]

    return [
        ("washer", lambda: 0.0, turn, lambda parts: parts[0][1].size),
        (
            "spin",
            lambda: spin_rng.uniform(0.0, SPIN_EVERY_S[1]) * rate,
            spin,
            lambda _: spin_rng.uniform(*SPIN_EVERY_S) * rate,
        ),
    ]


def _vacuum(config: FakeRoomConfig, rate: int, rng: np.random.Generator) -> StreamSpec:
    """On for :data:`~household_sounds.VACUUM_ON_S`, off for :data:`VACUUM_OFF_S`.

    At time 0 it may be running already, or switch on up to 20 s later.
    """
    motor_hz = rng.uniform(*VACUUM_MOTOR_HZ)

    def run() -> list[Part]:
        samples = household_sounds.vacuum_run(rate, rng, motor_hz)
        return [(0, rms_scaled(samples, config.vacuum_level_db))]

    def gap(parts: list[Part]) -> float:
        return parts[0][1].size + rng.uniform(*VACUUM_OFF_S) * rate

    first = rng.uniform(-household_sounds.VACUUM_ON_S[1], VACUUM_OFF_S[1]) * rate
    return ("vacuum", lambda: first, run, gap)
