"""Recorded sessions replayed offline: the belief computed again from the recorded steps.

A session is a bag written by recorder_node. With the recorded actions, replay joins
the recorded ``sound_step`` bits and ``vocalize_step`` decisions by step with the same
:class:`~infomax_contingency.core.stepclock.StepJoiner` and
:class:`~infomax_contingency.core.model.StatisticTracker` that belief_node runs, so the
replayed belief equals the recorded ``belief`` step for step (exactly: same code, same
inputs). Steps are windows of ``params.dt`` seconds, numbered from 1 within a stream.
The session is read by :func:`~infomax_contingency.eval.session_bag.load_session`.

Other actions (:func:`replay_bits`): a policy or rule deciding on the recorded bits (a
what-if: the recording does not answer other decisions), or, for a plain wav file
recorded elsewhere, decisions from an actions CSV file
(:func:`~infomax_contingency.sim.actions.read_actions_csv`, :func:`decisions_from_times`)
or from a channel carrying the robot's own output
(:func:`decisions_from_reference`), with the file's bits (:func:`wav_bits`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple, TypeVar

from infomax_contingency.audio.background import BackgroundThreshold, ordinal
from infomax_contingency.audio.bitsources.rules import Binarizer
from infomax_contingency.audio.calibration import dc_offset_note
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.audio.energy import wav_energies
from infomax_contingency.audio.threshold import (
    bits_from_energies,
    kmeans_split,
    require_separation,
)
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.core.controllers import Controller
from infomax_contingency.core.model import ModelParams, StatisticTracker, Withheld
from infomax_contingency.core.selfsound import GapWithholding
from infomax_contingency.core.stepclock import StepJoiner
from infomax_contingency.eval.session_bag import (  # noqa: F401 - read here too
    SESSION_TOPICS,
    RecordedSession,
    belief_model,
    check_belief_model,
    check_same_windows,
    check_window,
    load_session,
    session_memory,
)
from infomax_contingency.sim.loop import run_loop
from infomax_contingency.sim.simulation import StepRecord, statistic_record, step_record

ReplayT = TypeVar("ReplayT")


def with_session_model(session: RecordedSession, params: ModelParams,
                       replay: Callable[[ModelParams], tuple[bool, ReplayT]]
                       ) -> tuple[ModelParams, ReplayT, bool]:
    """``params``, or them with the other belief model where only that one replays equal.

    A session that says its belief model (``k2_per_lag``, :func:`check_belief_model`) is
    replayed with ``params``. One recorded before belief_node said it, whose beliefs
    ``replay(params)`` finds different, is replayed with the other model too; when that
    one equals, it is the session's. ``replay`` returns whether the beliefs equal, and
    its result. Returns the parameters chosen, their result and whether the model was
    told so (from the beliefs) rather than given.
    """
    same, result = replay(params)
    if same or session.k2_per_lag is not None:
        return params, result, False
    other = replace(params, k2_per_lag=not params.k2_per_lag)
    other_same, other_result = replay(other)
    return (other, other_result, True) if other_same else (params, result, False)


def replay_recorded(session: RecordedSession, params: ModelParams,
                    memory: int | None = None, resets: Collection[int] = (),
                    follow_restarts: bool = True, from_step: int = 1) -> Iterator[StepRecord]:
    """The steps of ``session`` with its recorded actions, as ``simulate --json`` rows.

    The bits and decisions are fed in the order they were recorded (a decision arrives
    after its step's bit); ``memory`` defaults to the session's (:func:`session_memory`).
    ``resets``: the steps (their index among those replayed, from 0) before which the
    history is forgotten, as belief_node's ``~/reset`` does between two steps. With
    ``follow_restarts``, the streams of a restarted mic_node follow, as belief_node
    follows them: the old stream's steps still awaiting a decision are applied without
    one, the counts are kept and the timer is forgotten (the gap between is not guessed).
    ``from_step`` > 1: as a belief_node that joined the first stream there (a restarted
    one): zero counts, the timer unknown until the next vocalization.
    """
    tracker = StatisticTracker(params, memory=session_memory(session, memory))
    out: list[StepRecord] = []
    applied = [0]

    def apply(step: int, y: bool | Withheld | None, u: bool | None) -> None:
        if applied[0] in resets:
            tracker.reset()
        if applied[0] == 0 and from_step > 1:  # joined there: the decisions before unknown
            tracker.forget_timer_completely()
        applied[0] += 1
        z = tracker.statistic.z
        statistic = tracker.observe_window(y)  # a withheld or missing bit is not counted
        heard = y.bit if isinstance(y, Withheld) else bool(y)
        out.append(statistic_record(params, step, (step - 1) * params.dt, z, int(heard),
                                    int(bool(u)), statistic))  # fmt: skip
        if u is None:
            tracker.act_unknown()
        else:
            tracker.act(u)

    streams = [(session.stream, session.bits, session.decisions)]
    streams += session.later_streams if follow_restarts else []
    joiner = StepJoiner(apply, max_pending=max(1, max(len(bits) for _, bits, _ in streams)))
    for index, (_, bits, decision_list) in enumerate(streams):
        if index:  # belief_node's switch to the stream the controller answers now
            joiner.finish()
            joiner.restart()
            tracker.forget_timer()
        decisions = dict(decision_list)
        for step, bit in bits:
            if index == 0 and step < from_step:
                continue
            joiner.bit(step, bit)
            if step in decisions:
                joiner.decision(step, decisions[step])
            yield from out
            out.clear()


# --------------------------------------------------------------------------------------
# What-if replays and plain wav files: actions from a policy, a CSV file or a channel.


class _RecordedBit(NamedTuple):
    """A recorded step's bit, and whether it was withheld (counted by no one)."""

    y: int
    withheld: bool = False


class _GivenBits:
    """A loop world that hears given bits whatever is decided (a recording)."""

    def __init__(self, bits: Sequence[bool | Withheld]) -> None:
        self.bits = iter(bits)

    def observe(self) -> _RecordedBit:
        bit = next(self.bits)
        if isinstance(bit, Withheld):
            return _RecordedBit(int(bit.bit), withheld=True)
        return _RecordedBit(int(bit))

    def act(self, u: int) -> None:
        """A recording does not answer."""


def replay_bits(bits: Sequence[bool | Withheld], controller: Controller, memory: int = 0
                ) -> Iterator[StepRecord]:
    """The steps of ``controller`` deciding on recorded ``bits``, as ``simulate --json`` rows.

    A recording does not answer the decisions: the bits are those recorded whatever the
    controller does, so with a policy in the loop this is a what-if on the same sound
    (a partner who would have answered other sounds is not simulated). The reported
    belief keeps ``memory`` counted observations (0 = all) and starts from zero counts,
    the timer "long ago".
    """
    loop = run_loop(_GivenBits(bits), controller, len(bits), memory=memory)
    return (step_record(controller.params, step) for step in loop)


def replay_windows(bits: Sequence[bool | None], decisions: Sequence[bool], params: ModelParams,
                   memory: int = 0) -> Iterator[StepRecord]:
    """A recording's windows with its own decisions, as ``simulate --json`` rows.

    ``bits[k]`` is window ``k``'s bit, None where it gave none (the threshold's warm-up):
    such a window is no step, but the decision taken after it (``decisions[k]``; 0 past
    their end) still moves the timer, so a robot that spoke during the warm-up has the
    windows after its sound counted in the agent period and the background, as they were,
    not as background. Steps count the windows with a bit, from 1, and ``time_s`` is
    their window's start in the recording (as an actions file's times); the belief keeps
    ``memory`` counted observations (0 = all) and starts from zero counts, the timer
    "long ago". With a bit in every window this is :func:`replay_bits` with
    :class:`~infomax_contingency.core.controllers.ReplayedDecisions`.
    """
    tracker = StatisticTracker(params, memory=memory)
    step = 0
    for k, bit in enumerate(bits):
        u = int(k < len(decisions) and bool(decisions[k]))
        if bit is None:
            tracker.skip_observation()
            tracker.act(u)
            continue
        step += 1
        z = tracker.statistic.z
        statistic = tracker.observe(bool(bit))
        yield statistic_record(params, step, k * params.dt, z, int(bool(bit)), u, statistic)
        tracker.act(u)


def recorded_bits(session: RecordedSession) -> list[bool | Withheld]:
    """The bits of the session's stream in step order (a step never recorded is skipped).

    A withheld step's bit is a :class:`~infomax_contingency.core.model.Withheld`.
    """
    return [bit for _, bit in sorted(dict(session.bits).items())]


def wav_bits(path: Path, window_s: float, channel: int | None, threshold_db: float | None,
             calibration_s: float) -> tuple[list[bool], float, list[str]]:
    """The bits of a wav file's windows, the threshold used (dB) and the input's problems.

    The microphone is ``channel`` (None: the mix of all channels), windowed and
    binarized as mic_node's ``source: wav`` does: ``threshold_db``, or the k-means
    calibration of the first ``calibration_s`` seconds (every window gets a bit).

    Raises:
        AudioError: unreadable file, missing channel, or a calibration that cannot
            separate sound from quiet.
    """
    replay = WavReplay(path, window_s, channel)
    binarizer = Binarizer(threshold_db)
    if threshold_db is None:
        try:
            binarizer.calibrate(replay.calibration_energies(calibration_s, window_s))
        except AudioError as error:
            raise AudioError(f"{error}{dc_offset_note(path, window_s, channel)}") from None
    bits, over_full_scale = [], 0
    while (energy := replay.next_energy()) is not None:
        bits.append(bool(binarizer.push(energy)))
        over_full_scale += energy > 0.0
    problems = [f"{over_full_scale} windows were louder than full scale (0 dB: samples beyond"
                " [-1, 1], a float file not scaled to full scale?): their levels are taken as"
                " they are"] if over_full_scale else []  # fmt: skip
    return bits, float(binarizer.threshold_db), problems


def wav_background_bits(
    path: Path,
    params: ModelParams,
    channel: int | None,
    decisions: Sequence[bool],
    **options: object,
) -> tuple[list[bool | None], str]:
    """The bits of a wav file's windows with the self-calibrating ``background`` threshold.

    The recording's own decisions (``decisions[k]``: the robot's sound was commanded after
    window ``k``, from an actions file or a reference channel) label its windows, so the
    threshold of window ``k`` is that of the background windows before it, as mic_node's
    would have been in the session. Windows of the warm-up give None (no step).
    ``options``: settings of the ``background`` bit source (``false_alarm``, ...:
    :mod:`~infomax_contingency.audio.bitsources.background`).

    Returns:
        the bits (None for a warm-up window) and one line saying what set the threshold.

    Raises:
        AudioError: unreadable file or missing channel.
    """
    from infomax_contingency.audio.bitsources import make_bit_source

    replay = WavReplay(path, params.dt, channel, samples=True)
    source = make_bit_source("background", PROCESSING_RATE_HZ, params.dt, **options)
    source.follow_model(params)
    rule = source.rule
    bits: list[bool | None] = []
    while (window := replay.next_window()) is not None:
        decision = int(decisions[len(bits)]) if len(bits) < len(decisions) else 0
        bits.append(source.push_recorded(window, decision))
    what = (
        f"sound threshold: the {ordinal(rule.rank)} loudest of the last {len(rule.background)}"
        f" background windows' {source.band_name} levels ({rule.threshold_db:.1f} dB at the"
        " end; false alarms"
        f" {rule.false_alarm_now:.3f})"
        if rule.threshold_db is not None
        else f"sound threshold: none, no bit: {_why_no_threshold(rule)}"
    )
    for problem in source.problems():  # clipping, DC offset, and the threshold's own
        what += f"; {problem}"
    return bits, what


def _why_no_threshold(rule: BackgroundThreshold) -> str:
    """Why a recording's windows never set a ``background`` threshold (one clause)."""
    heard = len(rule.background)
    if rule.windows <= rule.windows_before_first_bit:
        return (f"the recording's {rule.windows} windows are fewer than the warm-up's"
                f" {rule.warmup_windows} background windows and {rule.delay} more")  # fmt: skip
    return (f"only {heard} of its windows were background (timer past the agent period),"
            f" and {rule.warmup_windows} are needed first")


class _EndOfRecordingError(Exception):
    """The wav file of :class:`_WavLevels` has no more windows."""


class _WavLevels:
    """A loop world: a wav file's windows through a ``background`` threshold, in the loop.

    The decision on each bit labels the windows after it (as mic_node's ``source: wav``
    in lockstep); a window of the warm-up yields no step, and the bits right after
    windows without a step are withheld, as mic_node's
    (:class:`~infomax_contingency.core.selfsound.GapWithholding`).
    """

    def __init__(self, path: Path, params: ModelParams, channel: int | None, **options: object
                 ) -> None:
        from infomax_contingency.audio.bitsources import make_bit_source

        self.replay = WavReplay(path, params.dt, channel, samples=True)
        self.source = make_bit_source("background", PROCESSING_RATE_HZ, params.dt, **options)
        self.source.follow_model(params)
        self.gap = GapWithholding(params.ta2 + 1)
        self._withheld = False
        self.windows = 0
        """Windows read from the file so far (the last one's start: ``(windows - 1) dt``)."""

    def observe(self) -> _RecordedBit | None:
        window = self.replay.next_window()
        if window is None:
            raise _EndOfRecordingError
        self.windows += 1
        bit = self.source.push_window(window)
        if bit is None:
            self.gap.no_step()
            return None
        self._withheld = self.gap.bit()
        return _RecordedBit(int(bit), withheld=self._withheld)

    def act(self, u: int) -> None:
        self.gap.decided(self.gap.bits, u)
        self.source.note_decision(u, self._withheld)


def wav_background_loop(path: Path, params: ModelParams, channel: int | None,
                        controller: Controller, memory: int = 0,
                        problems: list[str] | None = None, **options: object
                        ) -> Iterator[StepRecord]:
    """``controller`` deciding on a wav file's bits of the ``background`` threshold (what-if).

    The controller's decisions label the windows, as they would live; the recording does
    not answer them (see :func:`replay_bits`). ``problems``: at the end of the recording,
    the bit source's lines (clipping, DC offset, the threshold's own) are added to it.
    A step's ``time_s`` is its window's start in the file (the warm-up's windows have no
    step), as with recorded actions.
    """
    world = _WavLevels(path, params, channel, **options)
    try:
        for step in run_loop(world, controller, None, memory=memory):
            record = step_record(controller.params, step)
            yield replace(record, time_s=round((world.windows - 1) * params.dt, 9))
    except _EndOfRecordingError:
        if problems is not None:
            problems.extend(world.source.problems())


def decisions_from_times(times: Sequence[float], windows: int, dt: float, what: str
                         ) -> list[bool]:
    """Per-step decisions from the moments the robot's sound was commanded (seconds).

    Convention (the graph's timing): window ``k`` (from 0) covers ``[k dt, (k+1) dt)``;
    the decision on window ``k`` is taken at its end and its sound commanded then, so a
    command at time ``t`` lies in window ``j = floor(t / dt)`` and is the decision on
    window ``j - 1`` (``u = 1`` at step ``j``, counting steps from 1). A command in the
    first window follows no window and is refused, as are two in one window and a
    command at or after the end of the recording (``windows * dt``).

    Raises:
        ValueError: one of those, naming ``what`` (the actions file) and the time.
    """
    decisions = [False] * windows
    for t in times:
        if t >= windows * dt:  # before the division: a huge time overflows it
            window = windows
        else:
            window = math.floor(t / dt + 1e-9)
        if window >= windows:
            raise ValueError(f"{what}: time_s {t:g} lies beyond the recording"
                             f" ({windows * dt:g} s, {windows} windows of {dt:g} s)")
        if window == 0:
            raise ValueError(f"{what}: time_s {t:g} lies in the first window (before"
                             f" {dt:g} s), before any decision could have been taken")
        if decisions[window - 1]:
            raise ValueError(f"{what}: two sounds commanded in the window at"
                             f" {window * dt:g} s (one decision per window)")
        decisions[window - 1] = True
    return decisions


def decisions_from_reference(path: Path, channel: int, window_s: float,
                             min_separation_db: float = 10.0) -> tuple[list[bool], float]:
    """Per-step decisions from a channel carrying the robot's own output, and its threshold.

    Onset rule: the channel's windows are split into quiet and sounding by the k-means
    threshold of all its window energies (refused when the two clusters lie less than
    ``min_separation_db`` apart: a silent channel); a sounding window whose previous
    window is quiet is an onset, and an onset in window ``j`` is the decision on window
    ``j - 1`` (as :func:`decisions_from_times`). A sound already playing in the first
    window follows no decision: refused, as an actions file's time in the first window
    is (its chirp and any reply would be counted as background); two sounds in
    consecutive windows make one onset.

    Raises:
        AudioError: unreadable file or missing channel.
        ValueError: the channel holds no robot sound, or sounds in the first window.
    """
    energies = wav_energies(path, window_s, channel)
    try:
        fit = require_separation(kmeans_split(energies), min_separation_db)
    except AudioError as error:
        raise ValueError(f"--actions channel:{channel}: the channel holds no sound of the"
                         f" robot ({error})") from None
    sounding = bits_from_energies(energies, fit.threshold_db)
    if sounding[0]:
        raise ValueError(f"--actions channel:{channel}: the robot's sound already plays in the"
                         f" first window (before {window_s:g} s), before any decision could"
                         " have been taken: start the recording before the robot's first"
                         " sound")  # fmt: skip
    onsets = sounding[1:] & ~sounding[:-1]
    return [bool(u) for u in onsets] + [False], fit.threshold_db


OFFLINE_STREAM = 1
"""Stream id of a session made offline (:func:`write_offline_session`)."""
OFFLINE_CONTROLLER = 2
"""Controller id of a session made offline."""


def write_offline_session(directory: Path, bits: Sequence[bool], decisions: Sequence[bool],
                          beliefs: Sequence[float], dt: float, start_ns: int = 0,
                          withheld: Sequence[bool] = ()) -> Path:
    """A session bag of an offline run (e.g. the audio-level fake room's loop).

    It holds what a recorded graph run holds for replay and ``analyze``: ``/sound_step``
    and ``/sound`` (the bits), ``/vocalize_step`` and ``/vocalize`` (the decisions) and
    ``/belief``, message ``t`` (from 0) stamped ``start_ns + t dt`` (receive and publish
    time alike). No ``/diagnostics``: replays use the whole history unless told a memory.
    ``withheld[t]`` (default: none): window t was heard during the robot's own sound.
    """
    from infomax_contingency.audio.bag import BagWriter, encode

    writer = BagWriter(Path(directory))
    stream_qos = [{"history": 1, "depth": 1000, "reliability": 1, "durability": 2}]
    topics = {"/sound": "std_msgs/msg/Bool", "/sound_step": "std_msgs/msg/Int64MultiArray",
              "/vocalize": "std_msgs/msg/Bool",
              "/vocalize_step": "std_msgs/msg/Int64MultiArray", "/belief": "std_msgs/msg/Float64"}
    for topic, kind in topics.items():
        writer.add_topic(topic, kind, stream_qos)
    window_us = round(dt * 1e6)
    withheld = list(withheld) or [False] * len(bits)
    for t, (y, u, belief, w) in enumerate(zip(bits, decisions, beliefs, withheld, strict=True)):
        time_ns = start_ns + round(t * dt * 1e9)
        step = t + 1
        writer.write("/sound", encode("std_msgs/msg/Bool", data=bool(y)), time_ns)
        writer.write("/sound_step", encode("std_msgs/msg/Int64MultiArray",
                     data=[OFFLINE_STREAM, step, int(y), window_us, int(w)]), time_ns)
        writer.write("/vocalize", encode("std_msgs/msg/Bool", data=bool(u)), time_ns + 1)
        writer.write("/vocalize_step", encode("std_msgs/msg/Int64MultiArray",
                     data=[OFFLINE_STREAM, step, int(u), OFFLINE_CONTROLLER]), time_ns + 1)
        writer.write("/belief", encode("std_msgs/msg/Float64", data=float(belief)), time_ns + 2)
    writer.close()
    return Path(directory)
