"""The base class of the graph's nodes: subscriptions, start gate, intruders, diagnostics.

Diagnostics: each node publishes a ``diagnostic_msgs/DiagnosticArray`` on
``/diagnostics`` every ``diagnostics_period_s`` seconds (1 s by default), built directly
(no diagnostic_updater). A fault that is over returns the status to OK after
``fault_hold_s``; its count stays among the values.

Waiting is visible: a node that waits for an input (mic_node for ``audio``,
controller_node for ``sound_step``, belief_node for both step topics, posture_node for
``belief``, ...) calls :meth:`GraphNode.wait_visibly`: it logs at once (INFO) what it
waits for and again when the first message came, with the time waited; when nothing
has arrived after :data:`WAITING_NOTICE_S` seconds it logs once (WARN) how to provide
it, and its diagnostics say WARN "waiting for ..." until it arrives. Such an input arrives
steadily once it has started: when it then stops (nothing for :data:`STOPPED_NOTICE_S`
seconds, or a few of its usual intervals if longer: :mod:`~infomax_contingency.core.steady`),
the node logs once (WARN) the topic and how long it has been silent, its diagnostics say
WARN with ``TOPIC_silent_s`` among the values, and an INFO line says when it is back.

Intruders: a node that listens to a topic with one rightful publisher (``sound`` and
``sound_step``: mic_node; ``vocalize`` and ``vocalize_step``: controller_node; ``audio``:
a driver or the fake room, for mic_node reading it) watches
the publishers on it (:meth:`GraphNode.extra_publishers`) and reports a second one by
name, in a throttled WARN and an ERROR diagnostic while it lasts.

A node is built in two steps, as a managed node's configure and activate (ros2/demos'
``lifecycle_py/talker.py``), called in that order by :class:`GraphNode`'s constructor:
:meth:`GraphNode.configure` declares and checks the parameters (a bad one raises
:class:`~infomax_contingency.nodes.parameters.ConfigError`), :meth:`GraphNode.activate`
creates the publishers, subscriptions, services and timers; then the diagnostics start.
A refused node leaves nothing behind: when either step raises (a bad parameter, a missing
file or device), the half-built node is destroyed before the error goes on, so its
publishers and services do not outlive it in a process that carries on (an in-process
test, a composed bringup that reports the refusal).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from contextlib import suppress
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription
from rclpy.task import Future

from infomax_contingency.core.steady import SteadyInputs
from infomax_contingency.core.stepclock import (
    LockstepPacer,
    Pace,
    RecentEvents,
    StepPace,
    WriterSequence,
)
from infomax_contingency.nodes.parameters import ParameterReader
from infomax_contingency.nodes.qos import STREAM_QOS

DIAGNOSTICS_PERIOD_S = 1.0
"""Seconds between diagnostics messages, by default (parameter ``diagnostics_period_s``)."""

_GATE_POLL_S = 0.02
"""Seconds between checks of a start gate."""

_TIMEOUT_POLL_S = 0.1
"""Seconds between checks of a lockstep timeout."""

_CONNECT_WAIT_S = 5.0
"""Seconds a start gate waits for seen but unconnected listeners."""

_STALLED_WARNING_S = 5.0
"""Seconds without a first decision before a lockstep node warns (and between warnings)."""

_INTRUDER_WARNING_S = 5.0
"""Seconds between warnings about the same kind of intrusion."""

THROTTLE_S = 5.0
"""Seconds between two log lines of one kind about a repeated fault (see log_throttled)."""

RELEASED_WINDOW = "the next window anyway"
"""How a lockstep clock node's warning ends when it released a window without its decision
(the demo counts these lines in the clock node's log)."""

WAITING_NOTICE_S = 5.0
"""Seconds without an awaited input before a node says what it waits for."""

STOPPED_NOTICE_S = WAITING_NOTICE_S
"""Seconds without a message on a steady input that had come before a node says it stopped
(at the least: a few of the input's usual intervals if longer; see core.steady)."""

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


class GraphNode(Node):
    """Base of the graph's nodes: parameters, diagnostics and a completion future.

    Subclasses set :attr:`NODE_NAME`, implement :meth:`configure`, :meth:`activate` and
    :meth:`diagnostic_status`. A node that finishes on its own (e.g. the end of a replayed
    file) sets :attr:`finished`; :func:`run_node` then returns its result as exit status.
    """

    NODE_NAME: str = ""
    """The node's default name."""

    WATCHED_TOPICS: tuple[str, ...] = ()
    """Topics with one rightful publisher that this node watches for a second one."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NODE_NAME, **kwargs)
        try:
            self.intruders: dict[str, list[str]] = {}  # watched topics -> their publishers
            self.started_ns = time.time_ns()
            self.stale_messages = 0
            """Messages ignored because they were published before this node started."""
            self.sequence: int | None = None
            """The DDS sequence number of the message being received (see subscribe)."""
            self.parameters = ParameterReader(self)
            self.fault_hold_s = self.parameters.number(
                "fault_hold_s",
                10.0,
                "A diagnostic shows a fault (WARN or ERROR) for this long after it last happened;"
                " its count stays among the values",
                0.1,
                3600.0,
                "s",
            )
            self.diagnostics_period_s = self.parameters.number(
                "diagnostics_period_s",
                DIAGNOSTICS_PERIOD_S,
                "Seconds between two diagnostics messages of this node on /diagnostics (each one"
                " also checks the watched topics for a second publisher)",
                0.05,
                60.0,
                "s",
            )
            if self.fault_hold_s < self.diagnostics_period_s:
                self.get_logger().warning(
                    f"fault_hold_s ({self.fault_hold_s:g} s) is shorter than diagnostics_period_s"
                    f" ({self.diagnostics_period_s:g} s): a fault that starts and ends between two"
                    " diagnostics messages shows only in the counts"
                )
            self.finished: Future = Future()
            self._quiet_until: dict[str, float] = {}
            """Throttled log kind -> monotonic second until which it stays quiet."""
            self.arrivals: dict[str, int] = {}
            """Messages received per topic (as subscribed, relative names)."""
            self.waiting_for = ""
            """What the node waits for (shown as a WARN diagnostic); empty when nothing."""
            self._awaited: list[tuple[str, str]] = []
            self._waiting_since_s: dict[str, float] = {}
            """Topics waited for visibly, nothing received yet -> when the wait began (now_s)."""
            self._visible_wait_since_s = 0.0
            """When the first wait began (now_s); the WARN of check_waiting counts from it."""
            self.steady = SteadyInputs(STOPPED_NOTICE_S)  # the steady inputs: which stopped
            self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.configure()
            self.activate()
        except BaseException:
            # A refused node is destroyed (what it made goes with it) before the error goes on.
            try:
                self.destroy_node()  # the subclass's: releases a device it opened
            except Exception:  # noqa: BLE001 - set up only in part: the rclpy node alone
                with suppress(Exception):
                    Node.destroy_node(self)
            raise
        self.start_diagnostics()

    def configure(self) -> None:
        """Declare and check the node's parameters (ConfigError for a bad one)."""
        raise NotImplementedError

    def activate(self) -> None:
        """Create the node's publishers, subscriptions, services and timers."""
        raise NotImplementedError

    def subscribe(
        self,
        kind: type,
        topic: str,
        callback: Callable[[Any, int], None],
        qos: QoSProfile = STREAM_QOS,
    ) -> Subscription:
        """Subscribe; ``callback(msg, stamp)`` gets the publication stamp (ns, 0 = unknown).

        During the callback, :attr:`sequence` is the message's number among its writer's
        (DDS ``publication_sequence_number``; None if the middleware gives none).

        Messages published before this node started are ignored: a node that is
        restarted in the middle of a run does not act on the past (DDS may hand a late
        joiner recent samples from a writer's shared-memory history).
        """

        def receive(msg: Any, info: dict[str, Any]) -> None:
            self.count_arrival(topic)
            stamp = int(info.get("source_timestamp", 0))
            if 0 < stamp < self.started_ns:
                self.stale_messages += 1
                return
            self.sequence = info.get("publication_sequence_number")
            callback(msg, stamp)

        return self.create_subscription(kind, topic, receive, qos)

    def start_when_ready(
        self,
        ready: Callable[[], bool],
        delay_s: float,
        start: Callable[[], None],
        pacer: LockstepPacer | None = None,
        on_timeout: Callable[[], None] | None = None,
        stalled_hint: str = "",
        waiting_for: str = "",
    ) -> None:
        """Call ``start`` once ``ready()`` has held for ``delay_s`` seconds.

        The start gate of a node that sets the pace of the graph: ``ready`` checks that
        its listeners are there; then every subscriber it sees on its topics must be
        connected (:meth:`listeners_connected`, waited for at most a few seconds); the
        delay lets the rest of the graph connect too. Afterwards, with a lockstep ``pacer``,
        ``on_timeout`` is called whenever the pacer's timeout expires; while the first
        window waits for its decision (no timeout applies then) a warning with
        ``stalled_hint`` is logged every few seconds. ``waiting_for`` is logged (INFO) now
        and, with the time waited, when the gate opens.
        """
        ready_since: list[float] = []
        connected_since: list[float] = []
        start = _announced_start(self.get_logger(), waiting_for, start) if waiting_for else start

        def check_timeout() -> None:
            now = time.monotonic()
            if pacer.timed_out(now):
                on_timeout()
            elif pacer.answers == 0 and pacer.waited_s(now) > _STALLED_WARNING_S:
                self.log_throttled(
                    "stalled",
                    "warning",
                    f"no 'vocalize' for the first window after {pacer.waited_s(now):.0f} s:"
                    f" {stalled_hint}",
                    _STALLED_WARNING_S,
                )

        def poll() -> None:
            now = time.monotonic()
            if not ready():
                ready_since.clear()
                connected_since.clear()
                return
            ready_since[:1] = ready_since[:1] or [now]
            # Listeners seen but not connected yet get a few seconds (one that can never
            # connect, e.g. with incompatible QoS, must not stop the graph).
            if self.listeners_connected() or now - ready_since[0] > _CONNECT_WAIT_S:
                connected_since[:1] = connected_since[:1] or [now]
            else:
                connected_since.clear()
            if not connected_since or now - connected_since[0] < delay_s:
                return
            gate.cancel()
            self.destroy_timer(gate)
            if pacer is not None and on_timeout is not None:
                self.create_timer(_TIMEOUT_POLL_S, check_timeout)
            start()

        gate = self.create_timer(_GATE_POLL_S, poll)

    def count_arrival(self, topic: str) -> None:
        """Count one message received on ``topic`` (done by :meth:`subscribe`).

        The first one on a topic waited for visibly is logged with the time waited, and
        the first one after a steady input was said to have stopped with its silence.
        """
        count = self.arrivals[topic] = self.arrivals.get(topic, 0) + 1
        for name, silent_s in self.steady.arrived(topic, self.now_s()):
            self.get_logger().info(
                f"'{self.resolve_topic_name(name)}' back after {silent_s:.1f} s without a message"
            )
        if count == 1 and topic in self._waiting_since_s:
            waited_s = self.now_s() - self._waiting_since_s.pop(topic)
            self.get_logger().info(
                f"'{self.resolve_topic_name(topic)}' received after {waited_s:.1f} s of waiting"
            )

    def wait_visibly(
        self, topic: str, hint: str, steady: bool = True, companions: tuple[str, ...] = ()
    ) -> None:
        """Log that this node waits for ``topic``, and again when it came (with the wait).

        When nothing arrives within :data:`WAITING_NOTICE_S` s, a warning says so with
        ``hint``, how to provide it (e.g. which node publishes it). Checked by
        :meth:`check_waiting` with each diagnostics message (every diagnostics_period_s).
        A ``steady`` input (one that comes every window or faster once it has started)
        that stops is said too (:data:`STOPPED_NOTICE_S`); a message on one of
        ``companions`` counts as one of its own (``no_step``: mic_node's windows without a
        step; the node counts them with :func:`count_only`).
        """
        if steady:
            self.steady.watch(topic, companions)
        if not self._awaited:
            self._visible_wait_since_s = self.now_s()
        self._awaited.append((topic, hint))
        if not self.arrivals.get(topic):
            self._waiting_since_s[topic] = self.now_s()
            self.get_logger().info(f"waiting for '{self.resolve_topic_name(topic)}'")

    def check_waiting(self, waited_s: float) -> str:
        """After ``waited_s`` seconds: what is still awaited (logged once per topic).

        An input whose companion came (``no_step``: mic_node calibrating) is not missing:
        its source is alive and says why it pauses.
        """
        missing = [(t, h) for t, h in self._awaited
                   if not self.arrivals.get(t) and not self.steady.heard(t)]
        if waited_s < WAITING_NOTICE_S or not missing:
            self.waiting_for = ""
            return ""
        waiting = "; ".join(
            f"waiting for '{self.resolve_topic_name(topic)}' ({hint})" for topic, hint in missing
        )
        if waiting != self.waiting_for:
            self.get_logger().warning(f"nothing received after {waited_s:.0f} s: {waiting}")
        self.waiting_for = waiting
        return waiting

    def recent_events(self) -> RecentEvents:
        """A fault counter whose diagnostic returns to OK ``fault_hold_s`` after the fault."""
        return RecentEvents(hold_s=self.fault_hold_s)

    @staticmethod
    def sent_s(stamp_ns: int, fallback_s: float) -> float:
        """When a message was published (s, system clock), or ``fallback_s`` if unknown.

        A source lock measures a followed source's silence between publication times, so
        a node that falls behind (a backlog under load) does not mistake its own delay
        for the source's silence.
        """
        return stamp_ns / 1e9 if stamp_ns > 0 else fallback_s

    def now_s(self) -> float:
        """Monotonic seconds (the clock of the step-clock bookkeeping)."""
        return time.monotonic()

    def extra_publishers(self, topics: tuple[str, ...]) -> dict[str, list[str]]:
        """Topics of ``topics`` with more than one publisher -> the publishing nodes.

        Each of these topics has one rightful publisher in the graph; a second one (a
        second mic_node or controller_node, ``ros2 topic pub``) is named here.
        """
        found = {}
        for topic in topics:
            name = self.resolve_topic_name(topic)
            infos = self.get_publishers_info_by_topic(name)
            if len(infos) > 1:
                found[topic] = sorted(publisher_name(info) for info in infos)
        return found

    def warn_intrusion(self, message: str, kind: str = "intrusion") -> None:
        """A WARN about an intruder, throttled per ``kind`` (by default one for all)."""
        self.log_throttled(kind, "warning", message, _INTRUDER_WARNING_S)

    def log_throttled(
        self, kind: str, level: str, message: str, period_s: float = THROTTLE_S
    ) -> None:
        """Log ``message`` at ``level`` unless a ``kind`` line came in the last ``period_s`` s.

        The throttle is checked here, before rclpy: rclpy's own ``throttle_duration_sec``
        looks up the caller's source line on every call, throttled or not (about 80 us),
        and a node that warns about each message of a flood spent a quarter of its time
        there.
        """
        now = self.now_s()
        if now < self._quiet_until.get(kind, -math.inf):
            return
        self._quiet_until[kind] = now + period_s
        self.log_at(level, message)

    def log_at(self, level: str, message: str) -> None:
        """Log at ``level`` (``error``, ``warning``, else info): the core's log callback.

        One call site per severity: rclpy refuses a call site whose severity changes.
        """
        logger = self.get_logger()
        if level == "error":
            logger.error(message)
        elif level == "warning":
            logger.warning(message)
        else:
            logger.info(message)

    def start_diagnostics(self) -> None:
        """Publish diagnostics every ``diagnostics_period_s`` seconds."""
        self.create_timer(self.diagnostics_period_s, self.publish_diagnostics)

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """``(level, message, key values)`` of the node's current state."""
        raise NotImplementedError

    def publish_diagnostics(self) -> None:
        """Check the watched topics for intruders, then publish this node's status.

        Also checks what the node still waits for (:meth:`wait_visibly`).
        """
        now_s = self.now_s()
        waited_s = now_s - self._visible_wait_since_s
        if self._awaited and waited_s >= WAITING_NOTICE_S:  # before, nothing to say
            self.check_waiting(waited_s)
        hints = dict(self._awaited)
        for topic, silent_s in self.steady.newly_silent(now_s):
            self.get_logger().warning(
                f"nothing on '{self.resolve_topic_name(topic)}' for {silent_s:.1f} s, after"
                f" {self.arrivals.get(topic, 0)} messages: it stopped ({hints[topic]})"
            )
        silent = self.steady.silent(now_s)
        notices = [self.waiting_for] if self.waiting_for else []
        notices += [f"nothing on '{self.resolve_topic_name(topic)}' for {silent_s:.0f} s"
                    for topic, silent_s in silent.items()]  # fmt: skip
        self.intruders = self.extra_publishers(self.WATCHED_TOPICS)
        for topic, names in self.intruders.items():
            self.warn_intrusion(
                f"{len(names)} publishers on '{topic}': {', '.join(names)}", f"publishers {topic}"
            )
        level, message, values = self.diagnostic_status()
        values.update({f"publishers_{t}": ", ".join(names) for t, names in self.intruders.items()})
        values.update({f"{topic}_silent_s": silent_s for topic, silent_s in silent.items()})
        if self.steady.stops:
            values["input_stops"] = self.steady.stops
        if notices and level == OK:
            level, message = WARN, "; ".join(notices)
        elif notices and level == WARN:
            message = "; ".join([message, *notices])
        status = DiagnosticStatus(
            level=level,
            # unique across robots: robot1/belief_node (the root namespace: belief_node)
            name=f"{self.get_fully_qualified_name().lstrip('/')}:"
            f" {type(self).__doc__.splitlines()[0].rstrip('.')}",
            message=message,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=key, value=_format_value(value)) for key, value in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def listeners_connected(self) -> bool:
        """True when every subscription this node sees on its topics is matched to it.

        A clock node checks this before its first message, so that a listener that has
        been discovered but not yet connected does not miss the first steps.
        """
        return all(
            pub.get_subscription_count() >= self.count_subscribers(pub.topic_name)
            for pub in self.publishers
        )

    def finish(self, exit_status: int = 0) -> None:
        """Ask :func:`run_node` to stop spinning and return ``exit_status``."""
        if not self.finished.done():
            self.finished.set_result(exit_status)


def count_only(node: GraphNode, kind: type, topic: str, qos: QoSProfile = STREAM_QOS
               ) -> Subscription:  # fmt: skip
    """Subscribe ``node`` to ``topic`` only to count its messages (raw: none is decoded).

    For a steady input's companion (:meth:`GraphNode.wait_visibly`): its messages say
    that the input's source is alive while the input itself pauses.
    """
    return node.create_subscription(kind, topic, lambda _data: node.count_arrival(topic), qos,
                                    raw=True)  # fmt: skip


def take_on_pace(node: GraphNode, pace: StepPace, jumps: RecentEvents, step: int,
                 sent_s: float, message: Any, kind: str, source: str) -> list[Any]:  # fmt: skip
    """The messages ``node`` takes now, after the pace of the step clock judged ``message``.

    ``message`` of ``source`` (e.g. "stream 4"), a ``kind`` (e.g. "bit") for ``step``
    published at ``sent_s``: itself if on pace; none if it jumps too far ahead (named in a
    WARN, counted in ``jumps``); the run it confirms, oldest first (logged).
    """
    verdict = pace.check(step, sent_s, message)
    if verdict is Pace.JUMP:
        jumps.note(node.now_s())
        node.warn_intrusion(pace.jump_message(f"{kind} for step {step} of {source}"), "jump")
        return []
    if verdict is Pace.CONFIRMED:
        taken = pace.take_confirmed()
        node.get_logger().warning(pace.run_message(source, taken[0].step))
        return taken
    return [message]


def take_from_writer(node: GraphNode, writer: WriterSequence, events: RecentEvents,
                     taken: list[Any], step: int, sequence: int | None, source: str
                     ) -> list[Any]:  # fmt: skip
    """``taken`` less its last message if another writer than ``source``'s sent it.

    ``taken`` is what :func:`take_on_pace` gave for a message of ``step``, numbered
    ``sequence`` by its writer (DDS); one from another writer was forged with the
    source's id: it is named in a WARN, counted in ``events`` and dropped.
    """
    if not taken or writer.same_writer(step, sequence):
        return taken
    events.note(node.now_s())
    node.warn_intrusion(f"step {step} of {source} comes from another writer than its earlier"
                        " steps (forged with its id?): ignored", "forged")  # fmt: skip
    return taken[:-1]


def _announced_start(logger: Any, waiting_for: str, start: Callable[[], None]
                     ) -> Callable[[], None]:
    """Log that a start gate waits for ``waiting_for``; ``start`` logging the time waited."""
    logger.info(f"waiting for {waiting_for}")
    since_s = time.monotonic()

    def announced() -> None:
        logger.info(f"{waiting_for}: there after {time.monotonic() - since_s:.1f} s of waiting")
        start()

    return announced


UNDISCOVERED_NODE = "_NODE_NAME_UNKNOWN_"
"""The node name the middleware gives an endpoint whose node it has not discovered yet."""


def publisher_name(info: Any) -> str:
    """The fully qualified name of an endpoint's node (``TopicEndpointInfo``), for a log line.

    An endpoint seen before its node (a ``ros2 topic pub`` just started, or one already
    gone) is "a node not discovered yet", not the middleware's placeholder.
    """
    if info.node_name == UNDISCOVERED_NODE:
        return "(a node not discovered yet)"
    return f"{info.node_namespace.rstrip('/')}/{info.node_name}"


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


