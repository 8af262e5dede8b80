"""mic_node's side of the robot's own sound: the ``self_sound`` topic and the window gate.

Any node declares the robot's own sound (speech, motors) on ``self_sound`` as a time
range on the ROS clock (:mod:`~infomax_contingency.core.selfsound`). :class:`SelfSoundInput`
subscribes it for a microphone node, checks every range (a refused, long or late one is
counted, logged in one WARN line per kind of problem, each kind throttled on its own, and
kept for the diagnostics), and holds each window in
the gate until it is known whether a declared range overlaps it. The decision itself is
the pure :class:`~infomax_contingency.core.selfsound.SelfSoundGate`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from std_msgs.msg import Int64MultiArray

from infomax_contingency.audio.windows import SourceWindow
from infomax_contingency.core.selfsound import SelfSoundGate, describe
from infomax_contingency.nodes.graph_node import GraphNode
from infomax_contingency.nodes.qos import STEP_READER_QOS
from infomax_contingency.nodes.step_topics import SELF_SOUND

POLL_S = 0.02
"""Seconds between two looks at the windows held (a held window's time is up)."""


class SelfSoundInput:
    """The ``self_sound`` subscription of ``node`` and the gate its windows wait in.

    Args:
        node: the microphone node (its clock, log and diagnostics).
        hold_s: seconds a window waits past its end while ``self_sound`` has a publisher.
        window_s: the window length, seconds (a replayed window's time range).
        on_time: called every :data:`POLL_S` while windows are held (the node releases
            what the gate lets go then).

    Attributes:
        gate: the pure gate; its items are ``(energy_db, bit, recorded_withheld)``.
        faults: when a range was last refused or late (the diagnostics' WARN).
    """

    def __init__(self, node: GraphNode, hold_s: float, window_s: float,
                 on_time: Callable[[], None]) -> None:  # fmt: skip
        self.node = node
        self.window_s = window_s
        self.gate = SelfSoundGate[tuple[float, bool, bool]](hold_s)
        self.faults = node.recent_events()
        self._subscription = node.subscribe(
            Int64MultiArray, SELF_SOUND, self._on_message, STEP_READER_QOS
        )
        node.create_timer(POLL_S, lambda: self.gate.waiting and on_time())

    def _now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def _on_message(self, msg: Int64MultiArray, stamp: int) -> None:
        verdict = self.gate.declare_fields(msg.data, self._now_ns())
        if verdict.problems:
            self.faults.note(self.node.now_s())
        for kind, line in verdict.problems:  # throttled per kind: one kind hides no other
            self.node.log_throttled(f"self_sound {kind}", "warning", line)

    def push(self, window: SourceWindow, energy_db: float, bit: bool, gap_before: bool) -> None:
        """A window's bit: it waits for the ranges that may overlap its time range.

        ``gap_before`` is carried along (mic_node's withholding after gaps).
        """
        span = window.time_range_ns(self._now_ns(), time.monotonic_ns(), self.window_s)
        self.gate.push(*span, (energy_db, bit, window.withheld, gap_before))

    def release(self, replaying_in_lockstep: bool) -> list[tuple[float, bool, bool, bool]]:
        """``(energy_db, bit, withheld, gap_before)`` of the windows that may go now, oldest first.

        Windows wait only while someone publishes on ``self_sound``; a replay in
        lockstep has no live sound to wait for.
        """
        if not self.gate.waiting:
            return []
        holding = not replaying_in_lockstep and self._subscription.get_publisher_count() > 0
        return [(energy_db, bit, withheld or recorded, gap)
                for (energy_db, bit, recorded, gap), withheld
                in self.gate.release(self._now_ns(), holding)]  # fmt: skip

    def values(self) -> dict[str, Any]:
        """Counts (declared, refused, late, withheld, held) and the latest problem."""
        return describe(self.gate)
