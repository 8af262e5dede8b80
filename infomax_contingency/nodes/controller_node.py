"""controller_node: answers every ``sound`` bit with one ``vocalize`` decision.

The decision comes from a solved policy table
(:class:`~infomax_contingency.core.controllers.PolicyController`): ``policy_file``, a file or
the name of a table in the package's ``policies/`` directory (default: the committed
robot table, found through the share directory). A table solved for other model
parameters than ``params`` is refused at start-up with the differences named. Episodic
tables restart an episode at their horizon; receding tables keep a sliding memory of M
counted observations. Sure of a partner (P(S=1) > ``check_in_above``), the node also
vocalizes after ``check_in_every_s`` without one
(:class:`~infomax_contingency.core.controllers.CheckIn`: the memory forgets, the table
does not know it). ``controller: interval:MIN_S-MAX_S`` replaces the table by the
paper's calibration protocol: vocalize at random intervals, uniform over MIN_S .. MAX_S
seconds, whatever is heard (seeded by the controller id, which is logged);
``controller: recorded:BAG`` answers step t of the stream with the decision the robot
recorded for step t in a session bag (for mic_node's ``source: bag``: a faithful
replay); a bag cut by a killed recorder is read up to its last chunk, with a WARN line
naming the cut.

Step clock: the node answers every bit on ``sound_step`` of the stream it follows
(:class:`~infomax_contingency.core.stepclock.SourceLock`: a second mic_node is counted
and ignored; a followed stream silent for ``source_timeout_s`` is replaced by the next
one heard, a restarted mic_node) with one decision, published on ``vocalize`` (Bool, for
the speaker) and on ``vocalize_step`` with the step it answers and this controller's id.
It answers once ``vocalize_step`` has ``wait_for_listeners`` subscribers, each connected
(so that its listeners all hear the same decisions): the last bit that came before is
then answered, earlier ones are not (counted as ``unanswered_before_start``).
Steps it never saw (it joined late, messages were lost) are counted, and their windows
passed without a bit and without a vocalization; a bit that repeats or goes backwards is
ignored, and one whose step jumps further ahead than the stream's pace allows
(:class:`~infomax_contingency.core.stepclock.StepPace`: a forged message) is named and
ignored (diagnostics ERROR) unless the stream goes on from there for
``source_timeout_s`` with nothing on pace meanwhile (its messages were lost). Bits whose
window length is not the model's dt are refused. A withheld bit (the window overlapped
the robot's declared own sound, ``self_sound``, or came right after windows without a
step) is answered like any other, but the statistic does not count it.

Subscribes ``sound_step`` (std_msgs/Int64MultiArray); publishes ``vocalize`` (Bool, one
per bit), ``vocalize_step`` (Int64MultiArray) and ``/diagnostics``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from std_msgs.msg import Bool, Int64MultiArray

from infomax_contingency.audio.common import AudioError
from infomax_contingency.core.controllers import (
    CHECK_IN_ABOVE,
    CHECK_IN_ABOVE_RANGE,
    CHECK_IN_EVERY_S,
    CHECK_IN_MAX_S,
    CheckIn,
    Controller,
    PolicyController,
    ReplayedDecisions,
    make_controller,
)
from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.stepclock import (
    Arrival,
    SourceLock,
    StepPace,
    WriterSequence,
)
from infomax_contingency.nodes.graph_node import (
    ERROR,
    OK,
    WARN,
    GraphNode,
    count_only,
    take_from_writer,
    take_on_pace,
)
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.step_topics import (
    NO_STEP,
    SOUND_STEP,
    VOCALIZE_STEP,
    StepBit,
    StepDecision,
    decision_message,
    new_source_id,
    parse_bit,
    window_us,
)
from infomax_contingency.resources import resource_path

DEFAULT_TABLE = ("policies", "robot_receding_H24_M60.npz")
"""The committed table for the ``robot`` parameters (share-directory relative)."""


def _table_path(value: str) -> str:
    """The table file: ``value`` itself, or a table of that name in ``policies/``."""
    name = value or DEFAULT_TABLE[1]
    if value and (Path(value).exists() or len(Path(value).parts) > 1):
        return value
    try:
        return str(resource_path(DEFAULT_TABLE[0], name))
    except FileNotFoundError as error:
        raise ConfigError(f"parameter 'policy_file' = {value!r}: {error}") from None


def _other_controller(spec: str, params: ModelParams, seed: int,
                      warn: Callable[[str], None]) -> Controller:  # fmt: skip
    """The controller of parameter ``controller``: interval:MIN_S-MAX_S or recorded:BAG.

    ``warn`` is told what a bag cut by a killed recorder lacks (its steps after the cut
    are answered False).
    """
    kind, _, argument = spec.partition(":")
    try:
        if kind == "interval":
            return make_controller(spec, params, np.random.default_rng(seed))
        if kind == "recorded" and argument:
            # Imported here: the bag library takes about 0.1 s of CPU to load, and only
            # this controller needs it (docs/ENVIRONMENT.md).
            from infomax_contingency.audio.bag_replay import recorded_decisions

            return ReplayedDecisions(params, recorded_decisions(Path(argument), warn),
                                     name=f"recorded:{argument}")
    except (ValueError, OSError, AudioError) as error:
        raise ConfigError(f"parameter 'controller' = {spec!r}: {error}") from None
    raise ConfigError(f"parameter 'controller' = {spec!r}: must be empty (the policy table),"
                      " interval:MIN_S-MAX_S (seconds, e.g. interval:3-6) or recorded:BAG (a"
                      " session bag's decisions)")


def _check_in(read: Any, params: ModelParams) -> CheckIn:
    """The check-ins of parameters ``check_in_every_s`` and ``check_in_above``."""
    every_s = read.number(
        "check_in_every_s", CHECK_IN_EVERY_S,
        "With the policy table: sure of a partner (P(S=1) > check_in_above), vocalize after"
        " this long without a vocalization (at least the reply period), as the belief forgets;"
        " 0 = the table alone",
        0.0, CHECK_IN_MAX_S, "s",
    )
    above = read.number(
        "check_in_above", CHECK_IN_ABOVE,
        "P(S=1) above which check_in_every_s applies (below it the table alone decides)",
        *CHECK_IN_ABOVE_RANGE,
    )
    return CheckIn.from_seconds(params, every_s, above)


class ControllerNode(GraphNode):
    """Controller: decides after every window whether to vocalize."""

    NODE_NAME = "controller_node"
    WATCHED_TOPICS = (SOUND_STEP,)

    def configure(self) -> None:
        """Declare and check the parameters; the state they set."""
        read = self.parameters
        params = read.model()
        path = read.text(
            "policy_file",
            "",
            "Policy table (.npz) solved for 'params': a file, or the name of a table in the"
            f" package's policies/ directory; empty = {DEFAULT_TABLE[1]}",
        )
        timeout_s = read.number(
            "source_timeout_s", SOURCE_TIMEOUT_S,
            "A followed mic_node stream silent this long is replaced by the next one heard",
            0.1, 3600.0, "s",
        )
        self.wait_for_listeners = read.integer(
            "wait_for_listeners", 2,
            f"Subscribers of '{VOCALIZE_STEP}' before the first decision (mic_node and"
            " belief_node; also fake_audio_node in lockstep)",
            0, 100,
        )
        spec = read.text(
            "controller", "",
            "Empty: decide with the policy table; interval:MIN_S-MAX_S: vocalize at random"
            " intervals, uniform over MIN_S .. MAX_S seconds (the calibration protocol);"
            " recorded:BAG: answer each step with a session bag's recorded decision",
        )
        check_in = _check_in(read, params)
        self.controller_id = new_source_id()
        self.table_path = _table_path(path)
        if spec:
            self.controller = _other_controller(spec, params, self.controller_id,
                                                self.get_logger().warning)
        else:
            table = PolicyTable.load(self.table_path, expected_params=params)
            self.controller = PolicyController(table, params, check_in)
        self.window_us = window_us(params.dt)
        self.streams = SourceLock(timeout_s)
        self.writer = WriterSequence()
        """The writer of the stream followed (a forged bit with its id is another)."""
        self.pace = StepPace(1.0 / params.dt, timeout_s)
        self.jumps = self.recent_events()
        self.last_step = 0
        self.steps = 0
        self.vocalizations = 0
        self.missed_steps = 0
        self.withheld_bits = 0
        self.stale_bits = self.recent_events()
        self.foreign = self.recent_events()
        self.bad = self.recent_events()
        if spec:
            self.get_logger().info(f"controller {self.controller.name} (no table);"
                                   f" controller id {self.controller_id}")
        else:
            self.get_logger().info(
                f"policy {self.table_path}: {table.mode}, horizon {table.horizon}"
                + (f", memory {table.memory}" if table.mode == "receding" else "")
                + f"; controller id {self.controller_id}"
            )

    def activate(self) -> None:
        """Publishers, subscriptions, services and timers."""
        self.vocalize_pub = self.create_publisher(Bool, "vocalize", STREAM_QOS)
        self.step_pub = self.create_publisher(Int64MultiArray, VOCALIZE_STEP, STREAM_QOS)
        self.subscribe(Int64MultiArray, SOUND_STEP, self._on_sound_step, STEP_READER_QOS)
        self.answering = False
        self.unanswered_bits = 0
        self._last_unanswered: tuple[Int64MultiArray, int] | None = None
        self.start_when_ready(
            self._listeners_ready, 0.0, self._start_answering,
            waiting_for=f"{self.wait_for_listeners} listeners on '{VOCALIZE_STEP}'",
        )  # fmt: skip
        count_only(self, Int64MultiArray, NO_STEP)
        self.wait_visibly(
            SOUND_STEP, "the bits of mic_node: is mic_node running and hearing audio?",
            companions=(NO_STEP,),
        )

    def _listeners_ready(self) -> bool:
        return self.step_pub.get_subscription_count() >= self.wait_for_listeners

    def _start_answering(self) -> None:
        """The listeners are connected: answer the last bit that came before, then all."""
        self.answering = True
        held, self._last_unanswered = self._last_unanswered, None
        if held is not None:
            self.unanswered_bits -= 1
        self.get_logger().info(
            f"listeners connected on '{VOCALIZE_STEP}': answering bits"
            + (f" ({self.unanswered_bits} earlier ones are not answered)"
               if self.unanswered_bits else "")
        )
        if held is not None:
            self.sequence = None  # its number is not known here: it is taken
            self._on_sound_step(*held)

    def _on_sound_step(self, msg: Int64MultiArray, stamp: int) -> None:
        if not self.answering:
            # A decision published before its listeners are connected would reach some
            # of them and not others: the belief would not be that of the true decisions.
            # The last bit waits (in lockstep its window waits for the answer); older
            # ones are not answered, and the listeners count them as missing decisions.
            self.unanswered_bits += 1
            self._last_unanswered = (msg, stamp)
            return
        bit = parse_bit(msg)
        now = self.now_s()
        if bit is None or bit.window_us != self.window_us:
            self.bad.note(now)
            self.log_throttled(
                "refused bit",
                "error",
                f"'{SOUND_STEP}' message refused: {list(msg.data)} (expected [stream, step,"
                f" bit, window_us] with window_us = {self.window_us}, the model's dt)",
            )
            return
        arrival = self.streams.accept(bit.stream, self.sent_s(stamp, now))
        if arrival is Arrival.FOREIGN:
            self.foreign.note(now)
            self.warn_intrusion(
                f"ignoring bits of stream {bit.stream} (a second mic_node?): answering stream"
                f" {self.streams.source}"
            )
            return
        if arrival is Arrival.SWITCHED:
            self.get_logger().warning(
                f"stream {self.streams.previous} went silent after step {self.last_step};"
                f" answering stream {bit.stream} from step {bit.step} (a restarted mic_node?)"
            )
            self.last_step = 0
            self.controller.missed(self.controller.params.timer_long_ago)
        if arrival is not Arrival.FOLLOWED:
            self.pace.restart()
            self.writer.restart()
        source = f"stream {bit.stream}"
        on_pace = take_on_pace(self, self.pace, self.jumps, bit.step, self.sent_s(stamp, now),
                               bit, "bit", source)  # fmt: skip
        for taken in take_from_writer(self, self.writer, self.foreign, on_pace, bit.step,
                                      self.sequence, source):  # fmt: skip
            self._answer(taken, now)

    def _answer(self, bit: StepBit, now: float) -> None:
        """Answer ``bit`` of the stream followed (unless it repeats or goes backwards)."""
        if bit.step <= self.last_step:
            self.stale_bits.note(now)
            self.warn_intrusion(
                f"bit for step {bit.step} repeats or goes backwards (last step"
                f" {self.last_step}): ignored"
            )
            return
        missed = bit.step - self.last_step - 1 if self.last_step or bit.step > 1 else 0
        if missed:
            self.missed_steps += missed
            self.controller.missed(missed)
        self.last_step = bit.step
        u = bool(self.controller.step(bit.observation))
        self.withheld_bits += bit.withheld
        self.steps += 1
        self.vocalizations += u
        self.vocalize_pub.publish(Bool(data=u))
        self.step_pub.publish(
            decision_message(StepDecision(bit.stream, bit.step, u, self.controller_id))
        )


    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Steps, vocalizations, the table, the stream followed and what was refused."""
        now = self.now_s()
        values = {
            "steps": self.steps,
            "last_step": self.last_step,
            "unanswered_before_start": self.unanswered_bits,
            "vocalizations": self.vocalizations,
            "missed_steps": self.missed_steps,
            "withheld_bits": self.withheld_bits,
            "stream": self.streams.source or "none yet",
            "controller_id": self.controller_id,
            "foreign_messages": self.foreign.count,
            "stale_bits": self.stale_bits.count,
            "refused_messages": self.bad.count,
            "stream_changes": self.streams.switches,
            "jumps_ignored": self.pace.jumps,
            "statistic": tuple(self.controller.tracker.statistic),
        }
        table = getattr(self.controller, "table", None)
        if table is None:
            values["controller"] = self.controller.name
        else:
            values.update(policy_file=self.table_path, mode=table.mode,
                          horizon=table.horizon, memory=table.memory,
                          check_ins=self.controller.check_ins,
                          check_in_every_steps=self.controller.check_in.every_steps,
                          check_in_above=self.controller.check_in.above)
        if self.intruders or self.foreign.recent(now) or self.bad.recent(now):
            return ERROR, "a second stream on 'sound_step', or refused messages", values
        if self.jumps.recent(now):
            return ERROR, "steps jumping ahead of the stream's pace (ignored)", values
        if not self.answering:
            waiting = f"waiting for {self.wait_for_listeners} listeners on '{VOCALIZE_STEP}'"
            return WARN, waiting, values
        if self.stale_bits.recent(now):
            return WARN, "repeated or backward steps (ignored)", values
        return OK, f"{self.steps} steps, {self.vocalizations} vocalizations", values


def main(args: list[str] | None = None) -> int:
    """Run the controller node."""
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    sys.exit(main())
