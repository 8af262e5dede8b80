"""The ``audio`` topic's contract (audio/contracts.py): mono, in [-1, 1], at its rate.

Breaches are counted, worded once and shown while they last.

The rate check runs on simulated publication times (no clock, no sleep): a live driver
at another rate is found; a live driver at the right rate with jitter, a lockstep replay,
bursts and pauses are not taken for one.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from infomax_contingency.audio.contracts import (
    PACED_SOURCES,
    RATE_SPAN_S,
    RATE_SUBSPANS,
    AudioContract,
    channel_dims,
    common_rate_near,
)

RATE_HZ = 16000


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def live_driver(rate_hz: int, seconds: float, chunk_s: float = 0.01, jitter_s: float = 0.05,
                start_s: float = 0.0, seed: int = 1) -> Iterator[tuple[int, float]]:  # fmt: skip
    """(samples, publication time) of a driver paced by a sound card at ``rate_hz``.

    Each chunk is published when its last sample was recorded, plus a delivery delay of
    up to ``jitter_s`` (in order: a later chunk is never published before an earlier one).
    """
    rng = np.random.default_rng(seed)
    n = round(rate_hz * chunk_s)
    last = start_s
    for k in range(1, int(seconds / chunk_s) + 1):
        last = max(last, start_s + k * chunk_s + rng.uniform(0.0, jitter_s))
        yield n, last


def feed(contract: AudioContract, chunks: Iterator[tuple[int, float]]) -> list[str]:
    warnings = []
    for samples, at_s in chunks:
        warnings += contract.check(np.zeros(samples, np.float32), (), at_s)
    return warnings


def test_samples_outside_minus_one_to_one_are_counted_worded_once_and_shown_for_a_while(
) -> None:  # fmt: skip
    clock = FakeClock()
    contract = AudioContract(RATE_HZ, hold_s=10.0, clock=clock)
    assert contract.check(np.float32([-1.0, 0.5, 1.0])) == []  # the bounds are allowed
    assert contract.problem() == ""
    loud = np.float32([0.1, 3e38, -2.0, 0.2])
    warnings = contract.check(loud)
    assert len(warnings) == 1 and "outside [-1, 1]" in warnings[0], warnings
    assert "2 of 4" in warnings[0] and "3e+38" in warnings[0]
    assert contract.check(loud) == []  # worded once
    assert contract.values()["chunks_out_of_range"] == 2
    assert contract.values()["samples_out_of_range"] == 4
    assert "outside [-1, 1]" in contract.problem()
    clock.now += 10.5
    assert contract.problem() == ""  # over; the counts stay
    assert contract.values()["chunks_out_of_range"] == 2


def test_a_multi_channel_layout_is_counted_worded_once_and_shown_for_a_while() -> None:
    clock = FakeClock()
    contract = AudioContract(RATE_HZ, hold_s=10.0, clock=clock)
    stereo = [("frames", 800), ("channels", 2)]
    for mono in ([], [("samples", 1600)], [("channels", 1), ("samples", 1600)]):
        assert contract.check(np.zeros(1600, np.float32), mono) == []
    warnings = contract.check(np.zeros(1600, np.float32), stereo)
    assert len(warnings) == 1 and "frames=800 x channels=2" in warnings[0], warnings
    assert contract.check(np.zeros(1600, np.float32), stereo) == []
    assert contract.values()["chunks_multichannel"] == 2
    assert "multi-channel" in contract.problem()
    clock.now += 11.0
    assert contract.problem() == ""


def test_channel_dims_and_common_rates() -> None:
    assert channel_dims([("a", 1), ("b", 5), ("c", 2)]) == [("b", 5), ("c", 2)]
    assert common_rate_near(48000 * 1.02) == 48000
    assert common_rate_near(44100 * 0.99) == 44100
    assert common_rate_near(46000) is None
    assert common_rate_near(16e6) is None


JUDGED_AFTER_S = RATE_SPAN_S * RATE_SUBSPANS


def test_48_khz_audio_into_a_16_khz_node_is_found_once_its_pace_is_steady() -> None:
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    chunks = list(live_driver(48000, JUDGED_AFTER_S + 5.0))
    early = [c for c in chunks if c[1] < JUDGED_AFTER_S - 0.5]
    assert feed(contract, iter(early)) == []  # too soon to tell
    warnings = feed(contract, iter(chunks[len(early):]))
    assert len(warnings) == 1, warnings
    assert "48000 Hz audio while audio_rate_hz is 16000" in warnings[0]
    assert "or a replay at a steady 3x real time" in warnings[0]
    assert contract.problem(0.0) == "audio at 48000 Hz, not audio_rate_hz 16000"
    assert feed(contract, live_driver(48000, 40.0, start_s=chunks[-1][1])) == []  # once
    assert contract.values()["rate_mismatches"] >= 2


@pytest.mark.parametrize("true_rate_hz", [8000, 44100])
def test_other_wrong_rates_are_named(true_rate_hz: int) -> None:
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    warnings = feed(contract, live_driver(true_rate_hz, JUDGED_AFTER_S + 5.0))
    assert len(warnings) == 1 and f"{true_rate_hz} Hz audio" in warnings[0], warnings


def test_the_mismatch_clears_when_the_audio_is_real_time_again() -> None:
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    feed(contract, live_driver(48000, JUDGED_AFTER_S + 5.0))
    assert contract.problem(0.0)
    end = contract.rate._last_at
    assert feed(contract, live_driver(RATE_HZ, JUDGED_AFTER_S + 15.0, start_s=end)) == []
    assert contract.problem(0.0) == ""


@pytest.mark.parametrize("jitter_s", [0.0, 0.05, 0.5])
def test_a_live_driver_at_the_stated_rate_is_never_taken_for_another_rate(
    jitter_s: float,
) -> None:
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    assert feed(contract, live_driver(RATE_HZ, 300.0, jitter_s=jitter_s)) == []
    assert contract.problem(0.0) == ""
    assert contract.rate.last_pace == pytest.approx(1.0, abs=0.06)


def test_a_lockstep_replay_faster_than_real_time_is_not_a_rate_mismatch() -> None:
    """One window per decision, as fast as the graph answers (0.2 - 5 ms a step)."""
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    rng = np.random.default_rng(2)
    at_s, chunks = 0.0, []
    for _ in range(30_000):  # about 80 s
        at_s += rng.uniform(0.0002, 0.005)
        chunks.append((8000, at_s))
    assert feed(contract, iter(chunks)) == []
    assert contract.rate.last_pace > 50  # far faster than any sound card


def steady_3x() -> Iterator[tuple[int, float]]:
    """One 0.5 s window every 1/6 s: a room in lockstep with ``lockstep_max_speed: 3``."""
    return ((8000, k * 0.5 / 3) for k in range(1, int(JUDGED_AFTER_S * 6) + 12))


def test_a_steady_3x_replay_is_told_apart_from_48_khz_audio_by_its_publisher_only() -> None:
    """The audio of a steady replay at 3x real time is that of a 48 kHz driver."""
    publishers: list[str] = ["my_driver"]
    contract = AudioContract(RATE_HZ, clock=FakeClock(), publishers=lambda: publishers)
    warnings = feed(contract, steady_3x())
    assert len(warnings) == 1 and "or a replay at a steady 3x real time" in warnings[0]
    for paced in PACED_SOURCES:
        publishers[:] = ["my_driver", paced]
        contract = AudioContract(RATE_HZ, clock=FakeClock(), publishers=lambda: publishers)
        assert feed(contract, steady_3x()) == []
        assert contract.problem(0.0) == ""


def test_bursts_and_pauses_of_a_live_driver_are_not_a_rate_mismatch() -> None:
    """A single 10^7-sample message, and pauses of 1.5 and 5 s, in a 16 kHz stream."""
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    chunks = list(live_driver(RATE_HZ, 200.0))
    burst_at = chunks[3000][1]
    chunks.insert(3001, (10**7, burst_at))
    paused = [(n, at + (1.5 if at > 60 else 0.0) + (5.0 if at > 120 else 0.0))
              for n, at in chunks]  # fmt: skip
    assert feed(contract, iter(paused)) == []
    assert contract.problem(0.0) == ""


def test_a_paused_driver_starts_the_check_again() -> None:
    """A driver that sends 1 s and pauses 3 s, over and over: no span is ever complete."""
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    chunks = ((160, cycle * 4.0 + k * 0.01) for cycle in range(50) for k in range(100))
    assert feed(contract, chunks) == []
    assert np.isnan(contract.rate.last_pace)


def test_lost_chunks_restart_the_rate_check() -> None:
    """A 16 kHz driver that loses every other chunk would look like 8 kHz audio."""
    contract = AudioContract(RATE_HZ, clock=FakeClock())
    warnings = []
    for k, (samples, at_s) in enumerate(live_driver(RATE_HZ, 3 * JUDGED_AFTER_S)):
        if k % 2:
            contract.chunks_lost()
            continue
        warnings += contract.check(np.zeros(samples, np.float32), (), at_s)
    assert warnings == []
    unnoticed = AudioContract(RATE_HZ, clock=FakeClock())  # the same without the report
    chunks = [c for k, c in enumerate(live_driver(RATE_HZ, 3 * JUDGED_AFTER_S)) if not k % 2]
    assert "8000 Hz audio" in feed(unnoticed, iter(chunks))[0]
