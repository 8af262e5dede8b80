"""belief_node: P(S=1 | history) from the bits and the decisions, once per step.

The statistic is the same :class:`~infomax_contingency.core.model.StatisticTracker` the
controller uses, with its own memory: ``memory_steps`` counted observations (0 = the
whole history; a bounded memory lets the belief fall again after a partner leaves).

Step clock: each ``vocalize`` is paired with the ``sound`` it answers, by their
publication stamps (:class:`~infomax_contingency.core.stepclock.StepPairer`, whatever order
they arrive in). Once both are in, the bit is counted, **then the belief is published**,
then the decision advances the timer. A node started in the middle of a run starts from
zero counts at the first step for which it received both messages.

Subscribes ``sound``, ``vocalize`` (Bool); publishes ``belief`` (Float64) and
``/diagnostics``; service ``reset`` (std_srvs/Trigger) forgets the history.
"""

from __future__ import annotations

import sys
from typing import Any

from std_msgs.msg import Bool, Float64
from std_srvs.srv import Trigger

from infomax_contingency.core.model import StatisticTracker
from infomax_contingency.core.stepclock import StepPairer
from infomax_contingency.nodes.graph_node import OK, WARN, GraphNode
from infomax_contingency.nodes.qos import STREAM_QOS
from infomax_contingency.nodes.runtime import run_node


class BeliefNode(GraphNode):
    """Belief: the posterior probability that a responsive partner is present."""

    NODE_NAME = "belief_node"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NODE_NAME, **kwargs)
        self.params = self.parameters.model()
        memory = self.parameters.integer(
            "memory_steps",
            0,
            "Counted observations the statistic keeps (a sliding memory); 0 = whole history",
            0,
            1_000_000,
        )
        self.tracker = StatisticTracker(self.params, memory=memory)
        self.pairer = StepPairer(self._on_bit, self._on_decision)
        self.belief = self.tracker.statistic.belief(self.params)
        self.resets = 0
        self.belief_pub = self.create_publisher(Float64, "belief", STREAM_QOS)
        self.subscribe(Bool, "sound", lambda msg, stamp: self.pairer.bit(msg.data, stamp))
        self.subscribe(Bool, "vocalize", lambda msg, stamp: self.pairer.decision(msg.data, stamp))
        self.create_service(Trigger, "reset", self._on_reset)
        self.start_diagnostics()

    def _on_bit(self, y: bool) -> None:
        self.belief = self.tracker.observe(y).belief(self.params)
        self.belief_pub.publish(Float64(data=self.belief))

    def _on_decision(self, u: bool) -> None:
        self.tracker.act(u)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.tracker.reset()
        self.belief = self.tracker.statistic.belief(self.params)
        self.resets += 1
        response.success = True
        response.message = f"statistic reset after {self.pairer.steps} steps"
        self.get_logger().info(response.message)
        return response

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Belief, statistic, steps and the pairing queues."""
        values = {
            "belief": self.belief,
            "statistic": tuple(self.tracker.statistic),
            "memory_steps": self.tracker.memory,
            "steps": self.pairer.steps,
            "pending_bits": self.pairer.pending_bits,
            "pending_decisions": self.pairer.pending_decisions,
            "dropped_decisions": self.pairer.dropped_decisions,
            "skipped_bits": self.pairer.skipped_bits,
            "resets": self.resets,
            "stale_messages": self.stale_messages,
        }
        if self.pairer.pending_bits > 2:
            return WARN, "bits are waiting for decisions (is the controller running?)", values
        return OK, f"P(S=1) = {self.belief:.4f}", values


def main(args: list[str] | None = None) -> int:
    """Run the belief node."""
    return run_node(BeliefNode, args)


if __name__ == "__main__":
    sys.exit(main())
