"""posture_node: the belief shown as a posture, ``attentive`` or ``bored``.

Hysteresis (:class:`~infomax_contingency.core.posture.PostureHysteresis`): attentive when the
belief rises above ``attentive_above``, bored again when it falls below ``bored_below``.
On every change (and once at start-up, with the initial posture) the node publishes
``posture`` (std_msgs/String) and ``joint_targets`` (trajectory_msgs/JointTrajectory:
one point, ``joint_names`` at ``attentive_positions`` or ``bored_positions``, reached in
``move_duration_s``), both transient-local so a late joiner gets the current posture.

With ``declare_motion_sound`` (live; off by default) every move is also declared as
the robot's own sound on ``self_sound`` (``[now, now + move_duration_s]`` on the ROS
clock, see :mod:`~infomax_contingency.core.selfsound`): the microphone hears the motors,
and the windows of the move are then not taken as evidence. Turn it on for a robot
whose microphone hears its motors; not against the simulated room, whose lockstep time
runs faster than the clock (and which has no motors).

Subscribes ``belief`` (Float64); publishes ``posture``, ``joint_targets``,
``self_sound`` (Int64MultiArray, with ``declare_motion_sound``), ``/diagnostics``. While
``belief`` has a second publisher (a plain Float64 names no sender) no belief is acted on:
the posture holds, a WARN and an ERROR status say so.
"""

from __future__ import annotations

import sys
from typing import Any

from builtin_interfaces.msg import Duration
from rclpy.publisher import Publisher
from std_msgs.msg import Float64, Int64MultiArray, String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S, WriterFollower
from infomax_contingency.core.posture import (
    ATTENTIVE,
    ATTENTIVE_ABOVE,
    BORED,
    BORED_BELOW,
    POSTURES,
    PostureHysteresis,
)
from infomax_contingency.nodes.graph_node import ERROR, OK, GraphNode, count_only
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import LATCHED_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.step_topics import NO_STEP, SELF_SOUND, self_sound_message

DEFAULT_JOINTS = ("head_pan", "head_tilt", "left_arm_lift", "right_arm_lift")
DEFAULT_ATTENTIVE = (0.0, 0.15, 0.3, 0.3)
DEFAULT_BORED = (0.6, -0.35, 0.0, 0.0)


class PostureNode(GraphNode):
    """Posture: attentive or bored, from the belief with hysteresis."""

    NODE_NAME = "posture_node"
    WATCHED_TOPICS = ("belief",)

    def configure(self) -> None:
        """Declare and check the parameters; the state they set."""
        read = self.parameters
        attentive_above = read.number(
            "attentive_above",
            ATTENTIVE_ABOVE,
            "Turn attentive when the belief rises above this (live)",
            0.0,
            1.0,
            read_only=False,
        )
        bored_below = read.number(
            "bored_below",
            BORED_BELOW,
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
        self.declare_motion_sound = read.flag(
            "declare_motion_sound", False,
            f"Declare every move on '{SELF_SOUND}' as the robot's own sound (live)",
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
        self.beliefs_ignored = 0
        """Beliefs not acted on: 'belief' had a second publisher, or another writer sent it."""
        self.ignored = self.recent_events()
        self.writer = WriterFollower(SOURCE_TIMEOUT_S)
        """belief_node's DDS numbering: a short-lived forger's message, gone from the
        graph before its callback runs, still shows as another writer's."""

    def activate(self) -> None:
        """Publishers, subscriptions, services and timers."""
        self.posture_pub = self.create_publisher(String, "posture", LATCHED_QOS)
        self.joints_pub = self.create_publisher(JointTrajectory, "joint_targets", LATCHED_QOS)
        self.self_sound_pub: Publisher | None = None
        """On ``self_sound`` while moves are declared: mic_node holds its windows while
        the topic has a publisher, so there is none otherwise."""
        self.motions_declared = 0
        self._set_declare_motion_sound(self.declare_motion_sound)
        self.subscribe(Float64, "belief", self._on_belief)
        count_only(self, Int64MultiArray, NO_STEP)  # beliefs paused, not stopped
        self.wait_visibly("belief", "P(S=1) from belief_node: is it running?",
                          companions=(NO_STEP,))  # fmt: skip
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
            lambda value: _check_thresholds(value, read.in_set("bored_below")),
        )
        read.live(
            "bored_below",
            lambda value: setattr(rule, "bored_below", value),
            lambda value: _check_thresholds(read.in_set("attentive_above"), value),
        )
        set_positions(ATTENTIVE)
        set_positions(BORED)
        read.live("move_duration_s", lambda value: setattr(self, "move_duration_s", value))
        read.live("declare_motion_sound", self._set_declare_motion_sound)

    def _set_declare_motion_sound(self, declare: bool) -> None:
        """Declare the moves from now on (or not): the publisher exists only then."""
        self.declare_motion_sound = declare
        if declare and self.self_sound_pub is None:
            self.self_sound_pub = self.create_publisher(Int64MultiArray, SELF_SOUND, STREAM_QOS)
        elif not declare and self.self_sound_pub is not None:
            self.destroy_publisher(self.self_sound_pub)
            self.self_sound_pub = None

    def _on_belief(self, msg: Float64, stamp: int) -> None:
        publishers, now = self.count_publishers("belief"), self.now_s()
        # a plain Float64 names no sender: while another publisher is there any belief may
        # be its, and one numbered out of belief_node's order is another writer's
        if publishers > 1 or not self.writer.take(self.sequence, now):
            self.beliefs_ignored += 1
            self.ignored.note(now)
            why = (f"{publishers} publishers on 'belief' (a forgery, or a belief_node that"
                   " crashed and is not gone from the graph yet)" if publishers > 1
                   else "it comes from another writer than belief_node's")  # fmt: skip
            self.warn_intrusion(f"belief {msg.data:.3f} ignored: {why}; the posture holds",
                                "publishers belief")  # fmt: skip
            return
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
        now = self.get_clock().now()
        trajectory.header.stamp = now.to_msg()
        if self.self_sound_pub is not None:  # the motors are heard until the move's end
            end_ns = now.nanoseconds + round(self.move_duration_s * 1e9)
            self.self_sound_pub.publish(self_sound_message(now.nanoseconds, end_ns))
            self.motions_declared += 1
        self.joints_pub.publish(trajectory)
        self.posture_pub.publish(String(data=posture))

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Posture, last belief, number of changes; ERROR while 'belief' has two publishers.

        A plain Float64 carries no identity: while a second publisher is there (``ros2
        topic pub``), every belief might be its, so none is acted on (the posture holds,
        a WARN says so) and the status is ERROR, also for a while after.
        """
        intruded = self.intruders or self.ignored.recent(self.now_s())
        return (
            ERROR if intruded else OK,
            f"another publisher on 'belief': {self.beliefs_ignored} beliefs ignored, the"
            " posture held" if intruded else self.hysteresis.posture,
            {"posture": self.hysteresis.posture, "belief": self.belief, "changes": self.changes,
             "motions_declared": self.motions_declared, "beliefs_ignored": self.beliefs_ignored},
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
