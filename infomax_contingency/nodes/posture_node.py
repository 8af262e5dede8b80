"""posture_node: the belief shown as a posture, ``attentive`` or ``bored``.

Hysteresis (:class:`~infomax_contingency.core.posture.PostureHysteresis`): attentive when the
belief rises above ``attentive_above``, bored again when it falls below ``bored_below``.
On every change (and once at start-up, with the initial posture) the node publishes
``posture`` (std_msgs/String) and ``joint_targets`` (trajectory_msgs/JointTrajectory:
one point, ``joint_names`` at ``attentive_positions`` or ``bored_positions``, reached in
``move_duration_s``), both transient-local so a late joiner gets the current posture.

Subscribes ``belief`` (Float64); publishes ``posture``, ``joint_targets``, ``/diagnostics``.
"""

from __future__ import annotations

import sys
from typing import Any

from builtin_interfaces.msg import Duration
from std_msgs.msg import Float64, String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from infomax_contingency.core.posture import ATTENTIVE, BORED, POSTURES, PostureHysteresis
from infomax_contingency.nodes.graph_node import OK, GraphNode
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import LATCHED_QOS
from infomax_contingency.nodes.runtime import run_node

DEFAULT_JOINTS = ("head_pan", "head_tilt", "left_arm_lift", "right_arm_lift")
DEFAULT_ATTENTIVE = (0.0, 0.15, 0.3, 0.3)
DEFAULT_BORED = (0.6, -0.35, 0.0, 0.0)


class PostureNode(GraphNode):
    """Posture: attentive or bored, from the belief with hysteresis."""

    NODE_NAME = "posture_node"

    def configure(self) -> None:
        """Declare and check the parameters; the state they set."""
        read = self.parameters
        attentive_above = read.number(
            "attentive_above",
            0.9,
            "Turn attentive when the belief rises above this (live)",
            0.0,
            1.0,
            read_only=False,
        )
        bored_below = read.number(
            "bored_below",
            0.2,
            "Turn bored when the belief falls below this (live)",
            0.0,
            1.0,
            read_only=False,
        )
        initial = read.text("initial_posture", BORED, "Posture at start-up", POSTURES)
        self.joint_names = read.texts(
            "joint_names", DEFAULT_JOINTS, "Joints moved by the posture (JointTrajectory names)"
        )
        self.positions = {
            ATTENTIVE: read.numbers(
                "attentive_positions",
                DEFAULT_ATTENTIVE,
                "Joint positions when attentive (rad, live)",
                read_only=False,
            ),
            BORED: read.numbers(
                "bored_positions",
                DEFAULT_BORED,
                "Joint positions when bored (rad, live)",
                read_only=False,
            ),
        }
        self.move_duration_s = read.number(
            "move_duration_s", 1.0, "Time to reach a new posture (live)", 0.0, 60.0, "s",
            read_only=False,
        )
        for posture, positions in self.positions.items():
            self._check_positions(posture, positions)
        _check_thresholds(attentive_above, bored_below)
        self.hysteresis = PostureHysteresis(attentive_above, bored_below, initial)
        self._make_live()
        self.changes = 0
        self.belief = float("nan")
        self._initial = initial

    def activate(self) -> None:
        """Publishers, subscriptions, services and timers."""
        self.posture_pub = self.create_publisher(String, "posture", LATCHED_QOS)
        self.joints_pub = self.create_publisher(JointTrajectory, "joint_targets", LATCHED_QOS)
        self.subscribe(Float64, "belief", self._on_belief)
        self._publish(self._initial)

    def _check_positions(self, posture: str, positions: list[float]) -> None:
        if len(positions) != len(self.joint_names):
            raise ConfigError(
                f"parameter '{posture}_positions' = {positions}: must hold one position per"
                f" joint in 'joint_names' ({len(self.joint_names)}: {self.joint_names})"
            )

    def _make_live(self) -> None:
        """Thresholds, joint targets and move time change at once on ``ros2 param set``."""
        read, rule = self.parameters, self.hysteresis

        def set_positions(posture: str) -> None:
            def apply(value: list[float]) -> None:
                self.positions[posture] = value
                if rule.posture == posture:
                    self._publish(posture)

            read.live(
                f"{posture}_positions", apply, lambda value: self._check_positions(posture, value)
            )

        read.live(
            "attentive_above",
            lambda value: setattr(rule, "attentive_above", value),
            lambda value: _check_thresholds(value, rule.bored_below),
        )
        read.live(
            "bored_below",
            lambda value: setattr(rule, "bored_below", value),
            lambda value: _check_thresholds(rule.attentive_above, value),
        )
        set_positions(ATTENTIVE)
        set_positions(BORED)
        read.live("move_duration_s", lambda value: setattr(self, "move_duration_s", value))

    def _on_belief(self, msg: Float64, stamp: int) -> None:
        self.belief = msg.data
        try:
            changed = self.hysteresis.update(msg.data)
        except ValueError as error:
            self.log_throttled("bad belief", "warning", f"belief ignored: {error}")
            return
        if changed is not None:
            self.changes += 1
            self.get_logger().info(f"{changed} (belief {msg.data:.3f})")
            self._publish(changed)

    def _publish(self, posture: str) -> None:
        seconds, nanoseconds = divmod(round(self.move_duration_s * 1e9), 10**9)
        point = JointTrajectoryPoint(
            positions=self.positions[posture],
            time_from_start=Duration(sec=seconds, nanosec=nanoseconds),
        )
        trajectory = JointTrajectory(joint_names=self.joint_names, points=[point])
        trajectory.header.stamp = self.get_clock().now().to_msg()
        self.joints_pub.publish(trajectory)
        self.posture_pub.publish(String(data=posture))

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Posture, last belief, number of changes."""
        return (
            OK,
            self.hysteresis.posture,
            {"posture": self.hysteresis.posture, "belief": self.belief, "changes": self.changes},
        )


def _check_thresholds(attentive_above: float, bored_below: float) -> None:
    """Refuse thresholds that would keep the posture from changing back."""
    if not bored_below < attentive_above:
        raise ConfigError(
            f"parameter 'bored_below' = {bored_below}: must be below 'attentive_above'"
            f" (= {attentive_above}), or the posture could not change back"
        )


def main(args: list[str] | None = None) -> int:
    """Run the posture node."""
    return run_node(PostureNode, args)


if __name__ == "__main__":
    sys.exit(main())
