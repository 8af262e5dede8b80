"""The self-calibrating threshold: a constant false-alarm rate on the model's background windows."""

from __future__ import annotations

import heapq
import math

import numpy as np
import pytest

from infomax_contingency.audio.background import (
    SELF_WINDOWS_WATCHED,
    BackgroundThreshold,
    DigitalSilenceWatch,
    rank_for,
    window_faults,
)
from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.bitsources.base import OUT_OF_RANGE
from infomax_contingency.audio.common import AudioError
from infomax_contingency.eval.rooms import binarizer_options, make_binarizer

TS1, TS2, TA2 = 0, 1, 4  # the robot's periods
RATE, WINDOW_S, N = 16000, 0.5, 8000


def timers(decisions: list[int]) -> list[int]:
    """The timer during each window, from the decision taken after each (brute force)."""
    z, out = TA2 + 1, []
    for u in decisions:
        out.append(z)
        z = 0 if u else min(z + 1, TA2 + 1)
    return out


def wilson(k: int, n: int, z: float = 3.29) -> tuple[float, float]:
    """Wilson interval of k successes in n (z = 3.29: 99.9 %)."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


@pytest.mark.parametrize("false_alarm", [0.05, 0.1, 0.2])
def test_false_alarm_share_on_background_windows_is_what_it_is_set_to(false_alarm: float) -> None:
    rng = np.random.default_rng(1)
    rule = BackgroundThreshold(
        TS1, TS2, TA2, false_alarm, history=60, warmup_windows=8, reference=False
    )
    active = counted = 0
    z = TA2 + 1
    for _ in range(20000):
        level = float(rng.normal(-50.0, 4.0))
        if TS1 <= z <= TS2:
            level += 30.0  # the robot hears itself
        bit = rule.push(level)
        if bit is None:
            continue
        if z > TA2 and len(rule.background) == 60:
            active += bit
            counted += 1
        u = int(rng.random() < 0.15)
        rule.note_decision(u)
        z = 0 if u else min(z + 1, TA2 + 1)
    expected = rank_for(false_alarm, 60) / 61  # k / (n + 1): exactly, for a steady room
    low, high = wilson(active, counted)
    assert counted > 5000
    assert low <= expected <= high, (active / counted, expected)
    assert abs(expected - false_alarm) < 1 / 61


def test_threshold_is_the_kth_largest_of_earlier_background_windows_only() -> None:
    """Self-feedback and agent-period windows (loud here) never set the threshold."""
    rng = np.random.default_rng(2)
    decisions = [int(t >= 10 and rng.random() < 0.2) for t in range(400)]  # none in warm-up
    z = timers(decisions)
    levels = [
        float(rng.normal(-45.0, 5.0)) + (40.0 if zt <= TA2 else 0.0) for zt in z
    ]  # every non-background window is 40 dB louder
    rule = BackgroundThreshold(TS1, TS2, TA2, 0.1, history=20, warmup_windows=5, reference=False)
    assert rule.delay == TA2 + 1
    background: list[tuple[int, float]] = []  # (window, level) of the background windows
    given = 0
    for t, level in enumerate(levels):
        known = [b for k, b in background if k <= t - rule.delay][-20:]
        if len(known) < 5:
            expected = None
        else:
            expected = heapq.nlargest(rank_for(0.1, len(known)), known)[-1]
        assert rule.threshold_db == expected, t
        bit = rule.push(level)
        assert (bit is None) == (expected is None)
        if bit is not None:
            assert bit == (level > expected)
            rule.note_decision(decisions[t])
            given += 1
        if z[t] > TA2:
            background.append((t, level))
    assert given > 300
    assert max(rule.background) < -10.0  # no loud (self or agent) window among them


def test_windows_wait_for_late_decisions_and_a_lost_one_hides_the_timer() -> None:
    rule = BackgroundThreshold(
        TS1, TS2, TA2, 0.2, history=10, warmup_windows=2, delay=1, reference=False
    )
    for level in (-60.0, -58.0):  # warm-up: no bits, labelled at once (timer long ago)
        assert rule.push(level) is None
    assert rule.labelled["background"] == 2
    assert rule.push(-40.0) is True  # awaits its decision
    assert rule.push(-59.0) is False  # its label waits for the decision before it
    assert rule.labelled["background"] == 3 and list(rule.background) == [-60, -58, -40]
    rule.note_decision(1)  # a vocalization: the window after it was self-feedback
    assert rule.labelled == {"background": 3, "agent": 0, "self": 1, "unknown": 0}
    assert list(rule.background) == [-60, -58, -40]
    rule.push(-59.0)
    rule.note_decision(None)  # lost: the timer is unknown from here
    rule.note_decision(0)
    for _ in range(8):
        rule.push(-50.0)
        rule.note_decision(0)
    # unknown until TA2 + 1 silent decisions put a lost vocalization past the agent period
    assert rule.labelled["unknown"] == TA2 + 1 and len(rule.background) == 3 + 9 - (TA2 + 1)
    rule.push(-50.0)
    rule.note_decision(1)  # a vocalization: the timer is known again
    for _ in range(6):
        rule.push(-51.0)
        rule.note_decision(0)
    assert rule.labelled["self"] == 3 and rule.labelled["agent"] == 3
    assert list(rule.background)[-1] == -51.0  # the 6th window after it is background
    with pytest.raises(AudioError, match="a decision came for no window that gave a bit"):
        rule.note_decision(0)
    with pytest.raises(AudioError, match="a decision is 0, 1 or None"):
        rule.note_decision(2)


def test_decisions_that_never_come_are_counted_and_said() -> None:
    rule = BackgroundThreshold(
        TS1, TS2, TA2, 0.1, history=10, warmup_windows=2, max_undecided=5, delay=1
    )
    for _ in range(20):
        rule.push(-50.0)
    assert rule.decisions_lost == 13  # 2 warm-up windows need none; 5 may wait
    assert any("decisions never came" in line for line in rule.problems())


def test_bad_levels_give_no_bit_and_a_clear_diagnostic() -> None:
    rule = BackgroundThreshold(TS1, TS2, TA2, 0.1, history=10, warmup_windows=2)
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(AudioError, match="window level must be finite"):
            rule.push(bad)
    with pytest.raises(AudioError, match="must be a number of dB"):
        rule.push("loud")  # type: ignore[arg-type]
    assert rule.windows == 0 and rule.problems() == []
    for _ in range(10):  # digital silence from the start (a dead input): not the room
        assert rule.push(-120.0) is None
    assert rule.background == [] and rule.calibrating
    [line] = rule.problems()
    assert "10 of 10 windows were digital silence" in line and "no window held sound" in line
    for level in (-50.0, -52.0, -120.0, -120.0, -51.0) * 2:  # then sound: heard from it on
        if rule.push(level) is not None:
            rule.note_decision(0)
    assert set(rule.background) == {-50.0, -51.0, -52.0, -120.0} and not rule.calibrating
    assert rule.push(-120.0) is False  # digital silence among the room's sound: bit 0
    rule.note_decision(0)
    assert rule.push(-40.0) is True
    assert rule.problems()[0].startswith("15 of 22 windows were digital silence")
    assert rule.problems()[0].endswith("; the first 10, before any sound, were not taken as the"
                                       " room")  # fmt: skip


def test_digital_silence_before_the_first_sound_changes_no_bit() -> None:
    """A recording that starts with zeros gives, after them, the bits of the sound alone."""
    rng = np.random.default_rng(8)
    sound = list(rng.normal(-50.0, 3.0, 200))

    def bits_of(levels: list[float]) -> list[bool | None]:
        rule = BackgroundThreshold(TS1, TS2, TA2, 0.05, history=60, warmup_windows=8,
                                   reference_margin_db=3.0, least_rank=2)  # fmt: skip
        out: list[bool | None] = []
        for level in levels:
            out.append(rule.push(level))
            if out[-1] is not None:  # a vocalization on every 7th bit
                rule.note_decision(int(sum(bit is not None for bit in out) % 7 == 0))
        return out

    alone = bits_of(sound)
    after_zeros = bits_of([-120.0] * 21 + sound)  # 21: the reference's 3 lags cycle alike
    assert after_zeros[:21] == [None] * 21
    assert after_zeros[21:] == alone
    assert sum(bit is True for bit in alone[:40]) <= 4  # a warm-up, not a burst of 1s


def test_the_silence_watch_says_a_dead_input_once_and_when_sound_is_back() -> None:
    watch = DigitalSilenceWatch(0.5, after_s=2.0)  # 4 windows
    quiet = np.random.default_rng(2).normal(0.0, 1e-4, N)  # -80 dB: sound, however faint
    said = [watch.push(x, 0.0) for x in [quiet, np.zeros(N), np.full(N, 0.3)] + [np.zeros(N)] * 3]
    assert said[:4] == [None] * 4 and watch.dead  # zeros, a constant: no sound
    assert said[4].startswith("the input has been digital silence for 2 s") and said[5] is None
    assert watch.message().startswith("the input has been digital silence for 2.5 s")
    assert watch.push(quiet, 0.0) == "sound again after 2.5 s of digital silence"
    assert not watch.dead and watch.push(None, -200.0) is None  # an energy only: of zeros
    assert watch.silent_run == 1 and watch.push(None, -80.0) is None and watch.silent_run == 0


def test_a_noise_gated_room_gets_a_threshold_from_its_silence() -> None:
    """All zeros between sounds: any sound the gate lets through is active, silence not."""
    rule = BackgroundThreshold(TS1, TS2, TA2, 0.05, history=40, warmup_windows=8)
    bits = []
    for k in range(100):
        level = -45.0 if k % 25 == 24 else -120.0  # the gate opens 1 window in 25
        bits.append(rule.push(level))
        if bits[-1] is not None:
            rule.note_decision(0)
    # heard from the first sound on (window 24): 8 background windows, 5 windows old; at
    # 49 the threshold is the loudest of 21 (the sound at 24), from 74 the 2nd of 40
    assert bits[:36] == [None] * 36 and [k for k, bit in enumerate(bits) if bit] == [74, 99]
    assert all(bit is False for bit in bits[36:] if bit is not True)  # silence: 0


def test_a_background_threshold_outside_the_parameters_range_gives_no_bits() -> None:
    """Unscaled float audio (levels far above 0 dB): no bits, a problem said, none made up."""
    said: list[str] = []
    source = make_bit_source("background", RATE, WINDOW_S, on_problem=said.append)
    rng = np.random.default_rng(5)
    bits = []
    for _ in range(60):
        bit = source.push_window(rng.normal(0.0, 1000.0, N))  # +56 dB in the speech band
        bits.append(bit)
        if bit is not None:
            source.note_decision(0)
    assert bits == [None] * 60
    assert source.state == OUT_OF_RANGE and source.calibrating
    assert "threshold_db 55.9" in source.problem
    assert "is not allowed: -150 .. 0 dB" in source.problem
    assert said == [source.problem]
    assert any("gave no bit" in line for line in source.problems())
    assert source.rule.range_guard.windows_out_of_range > 40


def test_a_room_louder_than_the_robot_is_said() -> None:
    rng = np.random.default_rng(3)

    def session(robot_db: float) -> BackgroundThreshold:
        """Vocalize after every 7th window: then self, self, agent x 3, background."""
        rule = BackgroundThreshold(TS1, TS2, TA2, 0.1, history=20, warmup_windows=5)
        while rule.push(float(rng.normal(-30.0, 3.0))) is None:
            pass
        rule.note_decision(0)
        for _ in range(2 * SELF_WINDOWS_WATCHED):
            for k in range(7):
                rule.push(max(robot_db, -30.0) + float(rng.normal(0.0, 3.0)) if k in (1, 2)
                          else float(rng.normal(-30.0, 3.0)))  # fmt: skip
                rule.note_decision(int(k == 0))
        return rule

    assert any("as loud as the robot's own sound" in line for line in session(-40.0).problems())
    assert session(-10.0).problems() == []


def test_clipping_dc_offset_and_nan_samples_through_the_bit_source() -> None:
    source = make_bit_source("background", RATE, WINDOW_S)
    rng = np.random.default_rng(4)
    with pytest.raises(AudioError):
        source.push_window(np.full(N, np.nan))
    assert source.rule.windows == 0
    clipped = np.clip(rng.normal(0.0, 0.8, N), -1.0, 1.0)
    offset = 0.3 + rng.normal(0.0, 0.01, N)
    assert window_faults(clipped).clipped and not window_faults(clipped).dc_offset
    assert window_faults(offset).dc_offset and not window_faults(offset).clipped
    assert window_faults(np.zeros(N)) == (False, False, True)
    for x in (clipped, offset):
        assert source.push_window(x) is None  # warming up: no bit yet
    problems = source.problems()
    assert any("clipped" in line for line in problems)
    assert any("DC offset" in line for line in problems)


def test_bad_settings_are_refused_by_name() -> None:
    for kwargs, message in (
        ({"false_alarm": 0.0}, "false_alarm must be in"),
        ({"false_alarm": 0.7}, "false_alarm must be in"),
        ({"history": 1}, "history must be a whole number >= 2"),
        ({"warmup_windows": 0}, "warmup_windows must be"),
        ({"history": 5, "warmup_windows": 6}, "must not exceed history"),
        ({"margin_db": -1.0}, "margin_db must be"),
    ):
        with pytest.raises(AudioError, match=message):
            BackgroundThreshold(TS1, TS2, TA2, **kwargs)
    with pytest.raises(AudioError, match="'warmup_s' = 40 s: must not exceed"):
        make_bit_source("background", RATE, WINDOW_S, warmup_s=40.0)
    with pytest.raises(AudioError, match="'rate_hz' = 6000: bit_source background with level_band"
                       " speech needs audio above 6800 Hz .* or set level_band: full"):
        make_bit_source("background", 6000, WINDOW_S)
    assert make_bit_source("background", 6000, WINDOW_S, level_band="full").samples_per_window
    with pytest.raises(AudioError, match="level_band = 'low' is not allowed: one of speech, full"):
        make_bit_source("background", RATE, WINDOW_S, level_band="low")


def test_the_binarizer_grammar_names_it() -> None:
    assert binarizer_options("background") == ("background", {})
    assert binarizer_options("background:0.05:6") == (
        "background",
        {"false_alarm": 0.05, "reference_margin_db": 6.0},
    )
    assert binarizer_options("background:0.05:3:full")[1]["level_band"] == "full"
    with pytest.raises(ValueError, match="background takes at most FALSE_ALARM and MARGIN_DB and"):
        binarizer_options("background:0.05:3:full:x")
    source = make_binarizer("background:0.2", WINDOW_S)
    assert source.needs_decisions and source.rule.false_alarm == 0.2
    assert source.rule.history == 60 and source.rule.warmup_windows == 8
    assert not make_binarizer("fixed:-40", WINDOW_S).needs_decisions


def test_reference_holds_agent_windows_to_the_window_the_robot_spoke_after() -> None:
    """An agent window must be louder than the window the vocalization was decided on."""

    def start(reference: bool) -> BackgroundThreshold:
        rule = BackgroundThreshold(
            TS1, TS2, TA2, 0.2, history=10, warmup_windows=8, delay=1, reference=reference
        )
        for _ in range(8):
            assert rule.push(-60.0) is None
        assert rule.push(-35.0) is True  # loud: the controller vocalizes after it
        rule.note_decision(1)
        for level in (-20.0, -25.0):  # self-feedback
            rule.push(level)
            rule.note_decision(0)
        assert rule.threshold_db == -60.0  # the 2nd loudest of 9 background windows
        return rule

    rule = start(reference=True)
    assert rule.reference_db(2) == -35.0
    assert rule.push(-40.0) is False  # above the room's threshold, not above -35 dB
    rule.note_decision(0)
    assert rule.reference_db(3) == -35.0
    assert rule.push(-30.0) is True  # louder than what the robot spoke into
    assert start(reference=False).push(-40.0) is True


def test_the_robots_own_sound_is_never_the_reference_of_a_background_window() -> None:
    """The robot's chirp changes no bit outside its own windows (against it muted).

    In a steady empty room the chirp (self-feedback windows, loud) must not silence the
    background windows whose reference it would be: they are held to the window the
    vocalization was decided on, as agent windows are.
    """

    def bits(chirp_db: float | None, late: int) -> tuple[list[bool | None], list[int]]:
        """The bits and timers; decisions ``late`` windows after their window (live: 1, 2)."""
        rng = np.random.default_rng(7)
        rule = BackgroundThreshold(TS1, TS2, TA2, 0.05, reference_margin_db=3.0)
        out: list[bool | None] = []
        z, z_of, pending = TA2 + 1, [], []
        for t in range(6000):
            level = float(rng.normal(-55.0, 3.0))
            if chirp_db is not None and TS1 <= z <= TS2:
                level = chirp_db
            out.append(rule.push(level))
            z_of.append(z)
            u = int(out[-1] is not None and t % 7 == 0)  # every 7 windows: z = 5, 6 after each
            if out[-1] is not None:
                pending.append(u)
            while len(pending) > late:
                rule.note_decision(pending.pop(0))
            z = 0 if u else min(z + 1, TA2 + 1)
        return out, z_of

    for late in (0, 1, 2):
        (played, z_of), (muted, _) = bits(-20.0, late), bits(None, late)
        outside = [t for t, z in enumerate(z_of) if z > TS2 and played[t] is not None]
        assert len(outside) > 4000
        assert [played[t] for t in outside] == [muted[t] for t in outside], late
        background = [played[t] for t in outside if z_of[t] > TA2]
        assert 0.02 < sum(background) / len(background) < 0.08, late


def test_in_a_bursty_empty_room_agent_windows_are_not_more_active_than_background() -> None:
    """Bursts of sound of several windows and a controller that speaks after loud windows.

    Without the reference, the agent windows that follow are active far more often than
    the background windows (evidence for a partner who is not there); the reference (3 dB)
    halves that excess at least (it does not remove it: see docs/RESULTS.md section 7).
    """

    def rates(reference: bool) -> tuple[float, float]:
        rng = np.random.default_rng(5)
        rule = BackgroundThreshold(
            TS1, TS2, TA2, 0.05, reference=reference, reference_margin_db=3.0
        )
        counts = {"agent": [0, 0], "background": [0, 0]}
        z, loud = TA2 + 1, 0
        for _ in range(10000):
            if loud == 0 and rng.random() < 0.03:
                loud = int(rng.integers(4, 12))
            level = float(rng.normal(-55.0, 2.0)) + (20.0 if loud else 0.0)
            loud = max(0, loud - 1)
            if TS1 <= z <= TS2:
                level = max(level, -20.0)
            bit = rule.push(level)
            if bit is None:
                continue
            where = "agent" if 2 <= z <= TA2 else "background" if z > TA2 else None
            if where:
                counts[where][0] += bit
                counts[where][1] += 1
            u = int(z > TA2 and (bit or rng.random() < 0.05))  # speaks after loud windows
            rule.note_decision(u)
            z = 0 if u else min(z + 1, TA2 + 1)
        return tuple(a / n for a, n in (counts["agent"], counts["background"]))

    agent, background = rates(reference=False)
    assert agent > 2.5 * background, (agent, background)  # the bias
    agent_referenced, background_referenced = rates(reference=True)
    excess, excess_referenced = agent - background, agent_referenced - background_referenced
    assert excess_referenced < 0.5 * excess, (agent_referenced, background_referenced)


def test_a_window_withheld_for_the_robots_own_sound_never_sets_the_threshold() -> None:
    rule = BackgroundThreshold(
        TS1, TS2, TA2, 0.2, history=10, warmup_windows=2, delay=1, reference=False
    )
    for level in (-60.0, -58.0):
        assert rule.push(level) is None
    rule.push(-20.0)  # background by the timer, but the robot was speaking (withheld)
    assert list(rule.background) == [-60.0, -58.0, -20.0]
    rule.note_decision(0, withheld=True)
    assert list(rule.background) == [-60.0, -58.0]
    rule.push(-10.0)  # labelled at once; withheld (taken back) when its decision says so
    rule.push(-59.0)
    rule.note_decision(0, withheld=True)
    rule.note_decision(0)
    assert list(rule.background) == [-60.0, -58.0, -59.0]


def test_a_lost_decision_leaves_the_timer_unknown_until_ta2_plus_1_silent_ones() -> None:
    """Then any vocalization it may have been is past the agent period: background again.

    A rule made anew in a session (a recalibration) starts the same way: a sound decided
    on the old rule's last bit may still be followed by a reply.
    """

    def labels(rule: BackgroundThreshold, lost_at: int | None, windows: int) -> list[str]:
        out = []
        for k in range(windows):
            before = dict(rule.labelled)
            if rule.push(-50.0 + (k % 3)) is not None:
                rule.note_decision(None if k == lost_at else 0)
            out.append(next(key for key in rule.labelled if rule.labelled[key] > before[key]))
        return out

    anew = BackgroundThreshold(TS1, TS2, TA2, 0.1, history=40, warmup_windows=2,
                               timer_known=False)  # fmt: skip
    assert labels(anew, None, 12) == ["unknown"] * (TA2 + 1) + ["background"] * (11 - TA2)
    rule = BackgroundThreshold(TS1, TS2, TA2, 0.1, history=40, warmup_windows=2)
    found = labels(rule, 10, 20)  # bits from window 7 on (warm-up and delay)
    assert found == (["background"] * 11 + ["unknown"] * (TA2 + 1)
                     + ["background"] * (20 - 11 - TA2 - 1))  # fmt: skip


def tone(hz: float, level_db: float, rng: np.random.Generator) -> np.ndarray:
    """A window of a sine at ``hz`` of RMS ``level_db`` over a white floor at -70 dB."""
    t = np.arange(N) / RATE
    amplitude = math.sqrt(2.0) * 10 ** (level_db / 20)
    return amplitude * np.sin(2 * np.pi * hz * t + rng.uniform(0, 2 * np.pi)) + rng.normal(
        0.0, 10 ** (-70 / 20), N
    )


@pytest.mark.parametrize("level_band", ["speech", "full"])
def test_a_rumble_outside_the_speech_band_does_not_hide_a_voice(level_band: str) -> None:
    """A room whose loud 80-Hz rumble comes and goes; a 1-kHz reply 15 dB under it.

    The speech band's level hears the reply over the rumble; the whole window's level
    (``full``) sets its threshold at the rumble and misses it.
    """
    rng = np.random.default_rng(3)
    source = make_bit_source("background", RATE, WINDOW_S, level_band=level_band)
    bits = []
    for k in range(80):  # background: the rumble in every other window
        bits.append(source.push_recorded(tone(80.0, -20.0 if k % 2 else -45.0, rng), 0))
    assert source.threshold_db is not None
    reply = source.push_recorded(tone(1000.0, -35.0, rng), 0)
    assert reply is (level_band == "speech")
    active = [b for b in bits[-40:] if b is not None]
    assert sum(active) <= 0.1 * len(active)
    assert source.rule.silent_windows == 0  # the rumble's windows hold sound, not silence


def test_a_window_with_sound_only_outside_the_band_is_not_digital_silence() -> None:
    rng = np.random.default_rng(4)
    source = make_bit_source("background", RATE, WINDOW_S)
    t = np.arange(N) / RATE
    hum = 0.1 * np.sin(2 * np.pi * 20.0 * t)  # far below the band: next to nothing in it
    for _ in range(20):
        source.push_recorded(hum + 1e-9 * rng.normal(size=N), 0)
    assert source.rule.silent_windows == 0
    assert not any("digital silence" in line for line in source.problems())
    source.push_recorded(np.zeros(N), 0)
    assert source.rule.silent_windows == 1


@pytest.mark.parametrize("level_band", ["speech", "full"])
def test_a_dead_input_holding_a_dc_value_is_digital_silence_in_either_band(level_band: str) -> None:
    source = make_bit_source("background", RATE, WINDOW_S, level_band=level_band)
    for _ in range(12):
        source.push_recorded(np.full(N, 0.01), 0)  # a constant: nothing but DC
    assert source.rule.silent_windows == 12
    assert any("digital silence" in line for line in source.problems())
    assert any("DC offset" in line for line in source.problems())


def test_a_nan_window_is_refused_and_spoils_no_later_window() -> None:
    rng = np.random.default_rng(6)
    source = make_bit_source("background", RATE, WINDOW_S)
    for _ in range(20):
        source.push_recorded(rng.normal(0.0, 0.01, N), 0)
    bad = rng.normal(0.0, 0.01, N)
    bad[100] = np.nan
    with pytest.raises(AudioError, match="finite"):
        source.push_recorded(bad, 0)
    for _ in range(5):
        source.push_recorded(rng.normal(0.0, 0.01, N), 0)
        assert math.isfinite(source.last_level_db)
    assert -46.0 < source.last_level_db < -42.0  # white noise at -40 dB: its speech band's share


def test_the_band_is_said_where_the_threshold_is() -> None:
    rng = np.random.default_rng(7)
    for level_band, words in (("speech", "speech-band"), ("full", "whole-window")):
        source = make_bit_source("background", RATE, WINDOW_S, level_band=level_band)
        for _ in range(12):
            source.push_recorded(rng.normal(0.0, 0.01, N), 0)
        assert source.threshold_db is not None
        assert f"({words} level)" in source.ready_message()
        assert f"background windows' {words} levels" in source.threshold_origin()
        assert source.diagnostic_values()["level_band"] == level_band
