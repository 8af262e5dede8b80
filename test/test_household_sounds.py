"""The later held-out rooms' sources: what they sound like, and that they change no other."""

from __future__ import annotations

import numpy as np
import pytest

from infomax_contingency.sim import household_sounds, household_streams, tts
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.sim.rooms import (
    HELD_OUT_BACKGROUNDS,
    HELD_OUT_LATER,
    ROOM_SOUNDS,
    ROOMS,
    audio_room_names,
)

RATE = 16000
ALONE = {  # the room's own source only: no floor, echo, hum, talkers or partner
    "noise_floor_db": -150.0, "reverb_rt60_s": 0.0, "hum_on": False, "babble_talkers": 0,
    "partner_arrive_s": -1.0,
}  # fmt: skip


def render(config: FakeRoomConfig, seconds: float, seed: int = 1) -> np.ndarray:
    room = FakeRoom(config, seed)
    return np.concatenate([room.next_window().samples for _ in range(round(2 * seconds))])


def frame_db(x: np.ndarray, frame_s: float) -> np.ndarray:
    n = round(frame_s * RATE)
    frames = x[: x.size // n * n].reshape(-1, n)
    return 10 * np.log10(np.mean(frames * frames, axis=1) + 1e-30)


def runs_of(flags: np.ndarray, frame_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Starts and ends (seconds) of the runs of True."""
    edges = np.diff(np.concatenate([[0], flags.astype(int), [0]]))
    return np.flatnonzero(edges == 1) * frame_s, np.flatnonzero(edges == -1) * frame_s


def f0_hz(x: np.ndarray, low_hz: float, high_hz: float) -> float:
    """The fundamental of a voiced sound: the autocorrelation's peak in the pitch range."""
    x = x - x.mean()
    c = np.correlate(x, x, "full")[x.size - 1 :]
    lo, hi = round(RATE / high_hz), round(RATE / low_hz)
    return RATE / (lo + int(np.argmax(c[lo:hi])))


LATER_SOURCES = {
    "children": {"children_talkers": 3},
    "toy": {"toy_rate_hz": 0.5},
    "bark": {"bark_rate_hz": 0.2},
    "washer": {"washer_on": True},
    "vacuum": {"vacuum_on": True},
}


@pytest.mark.parametrize("source", list(LATER_SOURCES))
@pytest.mark.parametrize("room", ["office+partner", "kitchen+partner", "street"])
def test_a_later_source_leaves_every_other_source_as_it_was(source: str, room: str) -> None:
    # the new source, inaudible (-150 dB): the rest of the room is the same, sample for sample
    silent = {f"{name}_level_db": -150.0 for name in ("children", "toy", "bark", "vacuum")}
    silent |= {"washer_level_db": -150.0, "washer_spin_level_db": -150.0}
    with_it = FakeRoom(FakeRoomConfig.preset(room, **LATER_SOURCES[source], **silent), 4, True)
    without = FakeRoom(FakeRoomConfig.preset(room), 4, True)
    for k in range(60):
        a, b = with_it.next_window().samples, without.next_window().samples
        np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-6)
        if k % 5 == 0:
            assert with_it.vocalize() == without.vocalize()
    levels = with_it.measured_levels_db()
    assert levels[source] < -140.0
    del levels[source]
    levels.pop("spin", None)
    assert levels == without.measured_levels_db()


def test_children_are_high_voices_talking_in_bursts() -> None:
    for voice in tts.children_bank(RATE):
        frames = voice[: voice.size // 640 * 640].reshape(-1, 640)
        loud = frames[np.sqrt(np.mean(frames * frames, axis=1)) > 0.5]
        assert np.median([f0_hz(frame, 120.0, 700.0) for frame in loud]) > 250.0
    x = render(FakeRoomConfig.preset("playroom", **ALONE, toy_rate_hz=0.0, children_talkers=1), 120)
    starts, ends = runs_of(frame_db(x, 0.05) > -90, 0.05)
    lengths = (ends - starts)[1:-1]  # the first and last may be cut off
    assert lengths.size > 10 and np.all(lengths <= 2.5 + 0.05)


def test_toys_are_short_high_sounds() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        x = household_sounds.toy_sound(RATE, rng)
        assert 0.1 <= x.size / RATE <= 0.8
        power = np.abs(np.fft.rfft(x)) ** 2
        high = power[np.fft.rfftfreq(x.size, 1 / RATE) > 1000].sum()
        assert high > 0.9 * power.sum()


def test_a_bark_is_harmonic_at_the_dogs_pitch() -> None:
    rng = np.random.default_rng(3)
    for f0 in (400.0, 600.0, 800.0):
        bark = household_sounds.dog_bark(RATE, rng, f0)
        assert 0.1 <= bark.size / RATE <= 0.3
        middle = bark[bark.size // 3 : 2 * bark.size // 3]
        assert 0.85 * f0 < f0_hz(middle, 300.0, 1200.0) < 1.45 * f0


def test_barks_come_in_clusters_every_12_to_20_s() -> None:
    x = render(FakeRoomConfig.preset("dog-home", **ALONE), 300)
    starts, ends = runs_of(frame_db(x, 0.01) > -80, 0.01)
    assert np.all((ends - starts <= 0.32) & (ends - starts >= 0.08))  # 10-ms frames
    gaps = starts[1:] - ends[:-1]
    within = gaps < 3.0
    assert np.all((gaps[within] > 0.18) & (gaps[within] < 0.62))
    cluster_starts = starts[np.concatenate([[True], ~within])]
    sizes = np.diff(np.flatnonzero(np.concatenate([[True], ~within, [True]])))
    assert set(sizes) <= {1, 2, 3, 4, 5} and len(set(sizes)) >= 3
    assert np.all((np.diff(cluster_starts) > 11.9) & (np.diff(cluster_starts) < 20.1))


def test_the_washer_turns_at_about_1_hz_and_its_spins_are_6_to_8_5_db_louder() -> None:
    x = render(FakeRoomConfig.preset("laundry", **ALONE), 120)
    envelope = frame_db(x[: 30 * RATE], 0.02)
    seconds = frame_db(x, 1.0)
    wash = seconds < -37.0
    envelope = envelope - envelope.mean()
    c = np.correlate(envelope, envelope, "full")[envelope.size - 1 :]
    turn_s = 0.02 * (30 + int(np.argmax(c[30:70])))  # lags 0.6 .. 1.4 s
    assert 1 / 1.2 - 0.05 < turn_s < 1 / 0.8 + 0.05
    assert abs(np.median(seconds[wash]) - (-40.0)) < 0.5
    raised = np.percentile(seconds[~wash], 75) - np.median(seconds[wash])
    assert 6.0 < raised < 8.5
    spins, _ = runs_of(~wash, 1.0)
    assert np.all((np.diff(spins) > 19) & (np.diff(spins) < 31))


def test_the_vacuum_switches_on_and_off_in_0_3_s() -> None:
    x = render(FakeRoomConfig.preset("vacuum-next-door", **ALONE), 240)
    half = frame_db(x, 0.5)
    starts, ends = runs_of(half > -80, 0.5)
    on, off = (ends - starts)[1:-1], (starts[1:] - ends[:-1])
    assert on.size >= 3 and np.all((on >= 5.0) & (on <= 25.5))
    assert np.all((off >= 4.5) & (off <= 20.0))
    assert abs(np.median(half[half > -80]) - (-36.0)) < 2.0
    run = household_sounds.vacuum_run(RATE, np.random.default_rng(5), 300.0)
    edges = frame_db(run, 0.05)
    assert edges[0] < np.median(edges) - 10 and edges[-1] < np.median(edges) - 10
    assert np.all(edges[6:-6] > np.median(edges) - 4)  # steady from 0.3 s in to 0.3 s out


def test_the_later_sources_have_streams_after_the_first_ones() -> None:
    assert household_streams.HOUSEHOLD_SOURCES == (
        "children", "toy", "bark", "washer", "spin", "vacuum",
    )  # fmt: skip
    # SeedSequence.spawn: the first children do not depend on how many are spawned
    few, more = (np.random.SeedSequence(7).spawn(n) for n in (13, 19))
    assert [s.spawn_key for s in few] == [s.spawn_key for s in more[:13]]
    assert all(
        np.array_equal(a.generate_state(4), b.generate_state(4))
        for a, b in zip(few, more, strict=False)
    )


ROOMS_BEFORE = {  # energy of 80 windows, seed 5, the robot asking every 6th: measured
    "office+partner": 881.1188874474881,  # before the later rooms' sources were added
    "street": 932.6504909831297,
    "cafe+leaving": 1304.2856566032997,
    "tv-switched-on+arriving": 757.7513840982043,
    "crowd-grows+partner": 1463.0286614792308,
    "kitchen+partner": 1143.7313579915278,
}


@pytest.mark.parametrize("name", sorted(ROOMS_BEFORE))
def test_the_rooms_built_before_sound_as_they_did(name: str) -> None:
    """Section 7's figures hold for these rooms only while their sound stays the same."""
    room = FakeRoom(FakeRoomConfig.preset(name), seed=5)
    energy = 0.0
    for k in range(80):
        if k % 6 == 2:
            room.vocalize()
        x = np.asarray(room.next_window().samples, dtype=np.float64)
        energy += float(np.dot(x, x))
    assert energy == pytest.approx(ROOMS_BEFORE[name], rel=1e-9), name


def test_the_later_held_out_rooms_are_registered_in_every_partner_state() -> None:
    assert not set(HELD_OUT_LATER) & set(HELD_OUT_BACKGROUNDS)
    for background in HELD_OUT_LATER:
        for name in audio_room_names(background):
            assert ROOMS[name].family == "audio" and ROOMS[name].audio is not None
    later = {"children_talkers", "toy_rate_hz", "bark_rate_hz", "washer_on", "vacuum_on"}
    for background, fields in ROOM_SOUNDS.items():  # their sources are theirs alone
        assert bool(later & set(fields)) == (background in HELD_OUT_LATER), background
