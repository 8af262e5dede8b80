"""The fault tests' yardstick: beliefs recomputed offline from the recorded steps.

After a fault, the belief stream a graph published must equal, step for step, the
beliefs of a fresh :class:`~infomax_contingency.core.model.StatisticTracker` fed the true
bits and decisions as recorded (the followed microphone stream and controller). Also the
diagnostics helpers those tests share: the last status of a node on ``/diagnostics``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_msgs.msg import Bool

from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.core.controllers import PolicyController, default_check_in
from infomax_contingency.core.model import ModelParams, StatisticTracker
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.stepfields import bit_of
from infomax_contingency.resources import resource_path
from infomax_contingency.testing.graph import StepRecorder

ROBOT = ModelParams.named("robot")
MEMORY = 60
"""The belief node's memory in the fault tests (counted observations)."""


def true_sources(recorder: StepRecorder) -> tuple[int, int]:
    """The first stream and the first controller recorded: the true ones."""
    return recorder.sound_step[0][0], recorder.vocalize_step[0][3]


def step_pairs(recorder: StepRecorder, stream: int, controllers: set[int], first: int,
               last: int) -> list[tuple]:  # fmt: skip
    """``(y, u)`` of steps ``first..last`` of ``stream`` as recorded (None: not recorded).

    Decisions count only from ``controllers``; a rogue's are left out. Fails if a step
    has two bits, or two decisions of those controllers.
    """
    bit_steps = [(fields[1], bit_of(fields).observation)  # type: ignore[union-attr]
                 for fields in recorder.sound_step if fields[0] == stream]
    decision_steps = [(s, bool(u)) for st, s, u, c in recorder.vocalize_step
                      if st == stream and c in controllers]  # fmt: skip
    bits, decisions = dict(bit_steps), dict(decision_steps)
    assert len(bits) == len(bit_steps), "a step of the stream has two bits"
    assert len(decisions) == len(decision_steps), "a step has two decisions of these controllers"
    return [(bits.get(s), decisions.get(s)) for s in range(first, last + 1)]


def offline_beliefs(segments: list[tuple[list, str]]) -> list[float]:
    """Beliefs from ``(steps, how)`` segments of ``(y, u)`` pairs (None: missing).

    ``y`` may be :class:`~infomax_contingency.core.model.Withheld`: not counted.

    ``how`` is ``"start"`` (a stream's first step), ``"joined"`` (in the middle of a
    stream: the timer unknown until the next vocalization) or ``"new stream"`` (counts
    kept across a gap of unknown length, the timer uncertain) or ``"reset"`` (the history
    forgotten, as by belief_node's ``~/reset``). The statistic starts from
    zero counts at the first segment; a "joined" later on keeps the counts.
    """
    tracker = StatisticTracker(ROBOT, memory=MEMORY)
    beliefs = []
    for pairs, how in segments:
        if how == "joined":
            tracker.forget_timer_completely()
        elif how == "new stream":
            tracker.forget_timer()
        elif how == "reset":  # belief_node's ~/reset between two steps
            tracker.reset()
        for y, u in pairs:
            tracker.observe_window(y)  # a bit; None (missing) or Withheld: not counted
            beliefs.append(tracker.statistic.belief(ROBOT))
            tracker.act_unknown() if u is None else tracker.act(u)
    return beliefs


def assert_same_beliefs(got: list[float], expected: list[float], log: str = "",
                        pairs: list[tuple] | None = None) -> None:  # fmt: skip
    """Equal to 1e-12, step for step; otherwise name the first step that differs.

    ``pairs``: the ``(y, u)`` the expected beliefs were computed from, shown around it.
    """
    assert len(got) == len(expected), f"{len(got)} beliefs, expected {len(expected)}\n{log}"
    assert np.isfinite(got).all(), f"a belief is not a number: {got}"
    differ = np.flatnonzero(~np.isclose(got, expected, rtol=0.0, atol=1e-12))
    if differ.size:
        first = int(differ[0])
        around = ""
        if pairs is not None:
            start = max(0, first - 5)
            around = f"; (y, u) from index {start}: {pairs[start:first + 5]}"
        assert differ.size == 0, (
            f"{differ.size} beliefs differ, the first at index {first}:"
            f" {got[max(0, first - 2):first + 3]} vs {expected[max(0, first - 2):first + 3]}"
            f"{around}\n{log}"
        )


def offline_steps(samples: np.ndarray) -> int:
    """The 0.5 s windows of ``samples`` (16 kHz): the steps the graph makes of them."""
    return len(window_energies_db(samples.astype(np.float64), 16000, 0.5))


def assert_offline_run(recorder: StepRecorder, samples: np.ndarray,
                       threshold_db: float = -40.0) -> None:  # fmt: skip
    """The recorded bits, decisions and beliefs are the offline ones of ``samples``.

    Offline: the window energies (16 kHz, 0.5 s), a fixed threshold, the robot's
    receding table (robot_receding_H24_M60.npz) and the belief with memory 60.
    """
    energies = window_energies_db(samples.astype(np.float64), 16000, 0.5)
    bits = [bool(e > threshold_db) for e in energies]
    assert [y for _, _, y, *_ in recorder.sound_step] == bits
    controller = PolicyController(PolicyTable.load(resource_path(
        "policies", "robot_receding_H24_M60.npz")), ROBOT, default_check_in(ROBOT))  # the node's
    decisions = [bool(controller.step(int(y))) for y in bits]
    assert [bool(u) for _, _, u, _ in recorder.vocalize_step] == decisions
    expected = offline_beliefs([(list(zip(bits, decisions, strict=True)), "start")])
    assert_same_beliefs(recorder.belief, expected)


def last_status(diagnostics: list[DiagnosticArray], node: str) -> DiagnosticStatus | None:
    """The last status of ``node`` received (its status name starts with the node name)."""
    for array_message in reversed(diagnostics):
        for status in array_message.status:
            if status.name.startswith(f"{node}:"):
                return status
    return None


def status_reported(diagnostics: list[DiagnosticArray], node: str, level: bytes, text: str,
                    found: list[DiagnosticStatus]) -> Callable[[], bool]:  # fmt: skip
    """A condition: ``node``'s last status has ``level`` and ``text``.

    ``text`` is looked for in the message and the key values; the status that matched is
    appended to ``found``.
    """

    def reported() -> bool:
        status = last_status(diagnostics, node)
        if status is None or status.level != level:
            return False
        words = status.message + " ".join(f"{v.key}={v.value}" for v in status.values)
        if text not in words:
            return False
        found.append(status)
        return True

    return reported


def values(status: DiagnosticStatus) -> dict[str, str]:
    """A status's key values."""
    return {v.key: v.value for v in status.values}


def an_intruder_is_named(harness: Any, topic: str, name: str) -> DiagnosticStatus:
    """Step until the belief node's ERROR names ``/name`` among the publishers of ``topic``.

    Discovery brings an intruding node's topics one at a time (a second controller is seen
    on ``vocalize`` before ``vocalize_step`` now and then), and its node name after its
    endpoints (for a moment its publisher is ``_NODE_NAME_UNKNOWN_``): the condition waits
    for both. ``harness``: as for :func:`a_stray_command_is_named`. Returns the status.
    """
    key = f"publishers_{topic}"

    def named() -> bool:
        status = harness.status("belief_node")
        return (status is not None and status.level == DiagnosticStatus.ERROR
                and f"/{name}" in values(status).get(key, "").split(", "))  # fmt: skip

    harness.run_until(named, f"belief_node to name /{name} among the publishers on {topic!r}")
    status = harness.status("belief_node")
    assert f"'{topic}'" in status.message, status.message
    return status


def a_stray_command_is_named(harness: Any) -> None:
    """One stray message on the plain command topic, as ``ros2 topic pub --once /vocalize``.

    The belief node must name its publisher (the probe) in an ERROR. ``harness``: a fault
    test's graph (``probe``, ``recorder``, ``run_until``, ``wait_status``).
    """
    stray = harness.probe.talk("vocalize", Bool)
    harness.run_until(lambda: harness.recorder.count_publishers("vocalize") == 2,
                      "the stray publisher")  # fmt: skip
    stray.publish(Bool(data=False))
    harness.wait_status("belief_node", DiagnosticStatus.ERROR, "/probe")
    harness.probe.destroy_publisher(stray)
