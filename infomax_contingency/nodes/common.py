"""What every node of the graph shares: QoS, parameter declaration, diagnostics, main().

* QoS: the step-clock topics (``audio``, ``sound``, ``sound_energy``, ``vocalize``,
  ``belief``, ``partner_present``) are reliable, keep-last :data:`STREAM_DEPTH`, so a
  lockstep replay never loses a message; slow-changing state (``posture``,
  ``joint_targets``) is reliable and transient-local with depth 1, so a late joiner gets
  the current value.
* Parameters are declared with a description and a range (``ros2 param describe``
  shows them); a bad value stops the node at start-up with one line naming the
  parameter, the value and what is allowed (:class:`ConfigError`), never a traceback.
  An integer given for a floating-point parameter (``-p window_s:=1``) is accepted.
* Diagnostics: each node publishes a ``diagnostic_msgs/DiagnosticArray`` on
  ``/diagnostics`` about once a second, built directly (no diagnostic_updater).
* :func:`run_node` is the body of every ``main()``: it spins the node until it is done
  or interrupted (Ctrl-C, SIGTERM) and ends with ``rclpy.try_shutdown()``.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from rclpy.task import Future

from ..model import ModelParams, ParameterError
from ..stepclock import LockstepPacer

STREAM_DEPTH = 100
"""History depth of the step-clock topics (messages kept for a slow reader)."""

STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=STREAM_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of the per-window topics."""

LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""QoS of slow-changing state: late joiners receive the last value."""

LATCHED_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""QoS to read slow-changing state: the last value on joining, then every change (a
deeper queue than the writer's, so two quick changes are both received)."""

DIAGNOSTICS_PERIOD_S = 1.0
"""Seconds between diagnostics messages."""

_GATE_POLL_S = 0.02
"""Seconds between checks of a start gate."""

_TIMEOUT_POLL_S = 0.1
"""Seconds between checks of a lockstep timeout."""

_CONNECT_WAIT_S = 5.0
"""Seconds a start gate waits for seen but unconnected listeners."""

_STALLED_WARNING_S = 5.0
"""Seconds without a first decision before a lockstep node warns (and between warnings)."""

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


class ConfigError(ValueError):
    """A parameter value the node cannot work with; the message says what is allowed."""


USER_ERRORS = (ValueError, OSError)
"""Errors that end a node with one log line and exit status 2: bad parameters
(:class:`ConfigError`, ``ParameterError``), tables (``PolicyTableError``), audio
(``AudioError``) — all ValueErrors — and unreadable files."""


def _range_text(low: float, high: float, unit: str) -> str:
    return f"a number in [{low:g}, {high:g}]" + (f" {unit}" if unit else "")


class ParameterReader:
    """Declares a node's parameters with descriptors and checks their values."""

    def __init__(self, node: Node) -> None:
        self._node = node

    def _declare(
        self,
        name: str,
        default: Any,
        descriptor: ParameterDescriptor,
        coerce: Callable[[Any], Any],
        allowed: str,
    ) -> Any:
        """Declare; on a value ROS refuses (type or range), explain it as a ConfigError."""
        descriptor.name = name
        descriptor.additional_constraints = allowed
        try:
            return coerce(self._node.declare_parameter(name, default, descriptor).value)
        except (InvalidParameterTypeException, InvalidParameterValueException):
            pass
        loose = ParameterDescriptor(name=name, dynamic_typing=True)
        raw = self._node.declare_parameter(name, default, loose).value
        self._node.undeclare_parameter(name)
        value = coerce(raw)  # raises ConfigError when the value cannot be used at all
        try:
            self._node.declare_parameter(name, value, descriptor, ignore_override=True)
        except (InvalidParameterTypeException, InvalidParameterValueException):
            raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}") from None
        return value

    def number(
        self,
        name: str,
        default: float,
        description: str,
        low: float,
        high: float,
        unit: str = "",
    ) -> float:
        """A floating-point parameter in ``[low, high]``."""
        allowed = _range_text(low, high, unit)

        def coerce(raw: Any) -> float:
            if isinstance(raw, bool) or not isinstance(raw, int | float):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            value = float(raw)
            if not math.isfinite(value) or not low <= value <= high:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return value

        descriptor = ParameterDescriptor(
            description=description,
            floating_point_range=[FloatingPointRange(from_value=low, to_value=high, step=0.0)],
        )
        return self._declare(name, float(default), descriptor, coerce, allowed)

    def integer(self, name: str, default: int, description: str, low: int, high: int) -> int:
        """An integer parameter in ``[low, high]``."""
        allowed = f"a whole number in [{low}, {high}]"

        def coerce(raw: Any) -> int:
            if isinstance(raw, bool) or not isinstance(raw, int) or not low <= raw <= high:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return int(raw)

        descriptor = ParameterDescriptor(
            description=description,
            integer_range=[IntegerRange(from_value=low, to_value=high, step=1)],
        )
        return self._declare(name, int(default), descriptor, coerce, allowed)

    def flag(self, name: str, default: bool, description: str) -> bool:
        """A boolean parameter."""
        allowed = "true or false"

        def coerce(raw: Any) -> bool:
            if not isinstance(raw, bool):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return raw

        return self._declare(
            name, bool(default), ParameterDescriptor(description=description), coerce, allowed
        )

    def text(
        self, name: str, default: str, description: str, choices: Sequence[str] | None = None
    ) -> str:
        """A string parameter, optionally one of ``choices``."""
        allowed = f"one of {', '.join(choices)}" if choices else "a string"

        def coerce(raw: Any) -> str:
            if not isinstance(raw, str) or (choices and raw not in choices):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return raw

        return self._declare(
            name, str(default), ParameterDescriptor(description=description), coerce, allowed
        )

    def texts(self, name: str, default: Sequence[str], description: str) -> list[str]:
        """A non-empty list of strings."""
        allowed = "a non-empty list of strings"

        def coerce(raw: Any) -> list[str]:
            if not isinstance(raw, list | tuple) or not raw:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            if not all(isinstance(item, str) and item for item in raw):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return list(raw)

        return self._declare(
            name, list(default), ParameterDescriptor(description=description), coerce, allowed
        )

    def numbers(self, name: str, default: Sequence[float], description: str) -> list[float]:
        """A non-empty list of finite numbers."""
        allowed = "a non-empty list of finite numbers"

        def coerce(raw: Any) -> list[float]:
            if not isinstance(raw, list | tuple) or not raw:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            if not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in raw
            ):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return [float(v) for v in raw]

        return self._declare(
            name,
            [float(v) for v in default],
            ParameterDescriptor(description=description),
            coerce,
            allowed,
        )

    def model(self) -> ModelParams:
        """The ``params`` parameter: a named model parameter set or a YAML file."""
        name = self.text(
            "params",
            "robot",
            "Model parameters (MODEL.md): a named set (robot, paper) or a YAML file holding"
            " dt, ts1, ts2, ta1, ta2, pi and optionally the Beta priors b11 .. b32",
        )
        try:
            return ModelParams.load(name)
        except ParameterError as error:
            raise ConfigError(f"parameter 'params' = {name!r}: {error}") from None


class GraphNode(Node):
    """Base of the graph's nodes: parameters, diagnostics and a completion future.

    Subclasses call :meth:`start_diagnostics` once set up and implement
    :meth:`diagnostic_status`. A node that finishes on its own (e.g. the end of a replayed
    file) sets :attr:`finished`; :func:`run_node` then returns its result as exit status.
    """

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.started_ns = time.time_ns()
        self.stale_messages = 0
        """Messages ignored because they were published before this node started."""
        self.parameters = ParameterReader(self)
        self.finished: Future = Future()
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)

    def subscribe(
        self,
        kind: type,
        topic: str,
        callback: Callable[[Any, int], None],
        qos: QoSProfile = STREAM_QOS,
    ) -> Subscription:
        """Subscribe; ``callback(msg, stamp)`` gets the publication stamp (ns, 0 = unknown).

        Messages published before this node started are ignored: a node that is
        restarted in the middle of a run does not act on the past (DDS may hand a late
        joiner recent samples from a writer's shared-memory history).
        """

        def receive(msg: Any, info: dict[str, Any]) -> None:
            stamp = int(info.get("source_timestamp", 0))
            if 0 < stamp < self.started_ns:
                self.stale_messages += 1
                return
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
    ) -> None:
        """Call ``start`` once ``ready()`` has held for ``delay_s`` seconds.

        The start gate of a node that sets the pace of the graph: ``ready`` checks that
        its listeners are there; then every subscriber it sees on its topics must be
        connected (:meth:`listeners_connected`, waited for at most a few seconds); the
        delay lets the rest of the graph connect too. Afterwards, with a lockstep ``pacer``,
        ``on_timeout`` is called whenever the pacer's timeout expires; while the first
        window waits for its decision (no timeout applies then) a warning with
        ``stalled_hint`` is logged every few seconds.
        """
        ready_since: list[float] = []
        connected_since: list[float] = []

        def check_timeout() -> None:
            now = time.monotonic()
            if pacer.timed_out(now):
                on_timeout()
            elif pacer.answers == 0 and pacer.waited_s(now) > _STALLED_WARNING_S:
                self.get_logger().warning(
                    f"no 'vocalize' for the first window after {pacer.waited_s(now):.0f} s:"
                    f" {stalled_hint}",
                    throttle_duration_sec=_STALLED_WARNING_S,
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

    def start_diagnostics(self, period_s: float = DIAGNOSTICS_PERIOD_S) -> None:
        """Publish diagnostics every ``period_s`` seconds."""
        self.create_timer(period_s, self.publish_diagnostics)

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """``(level, message, key values)`` of the node's current state."""
        raise NotImplementedError

    def publish_diagnostics(self) -> None:
        """Publish one DiagnosticArray with this node's status."""
        level, message, values = self.diagnostic_status()
        status = DiagnosticStatus(
            level=level,
            name=f"{self.get_name()}: {type(self).__doc__.splitlines()[0].rstrip('.')}",
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


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def device_parameter(node: Node, what: str) -> str:
    """Declare and read the ``device`` parameter: ``""``, an index or a part of a name.

    ``-p device:=3`` arrives as an integer, ``-p device:=USB`` as a string; both are
    accepted (the parameter is dynamically typed) and returned as text, which
    :func:`~infomax_contingency.live_audio.resolve_device` understands.
    """
    allowed = "empty (the system default), a device index, or a part of a device name"
    descriptor = ParameterDescriptor(
        name="device",
        description=f"{what}: empty = the system default, an index, or a part of its name"
        " (first match; `infomax-contingency devices` lists them)",
        additional_constraints=allowed,
        dynamic_typing=True,
    )
    value = node.declare_parameter("device", "", descriptor).value
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ConfigError(f"parameter 'device' = {value!r} is not allowed: {allowed}")
    return str(value).strip()


def init_ros(args: Sequence[str] | None, program: str) -> bool:
    """``rclpy.init``; malformed ``--ros-args`` give one line on stderr and False."""
    try:
        rclpy.init(args=args)
    except rclpy_implementation.RCLError as error:
        reason = str(error).split(", at ")[0]
        print(
            f"{program}: invalid ROS arguments: {reason} (a parameter is given as"
            " `-p name:=value` with a non-empty value)",
            file=sys.stderr,
        )
        return False
    return True


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until it finishes or is interrupted; return the exit status.

    Bad parameters and other user errors are logged as one error line (status 2);
    Ctrl-C and SIGTERM end the node cleanly (status 0).
    """
    if not init_ros(args, getattr(factory, "NODE_NAME", "node")):
        return 2
    executor = SingleThreadedExecutor()
    node = None
    try:
        node = factory()
        executor.add_node(node)
        finished = getattr(node, "finished", None) or Future()
        executor.spin_until_future_complete(finished)
        return int(finished.result()) if finished.done() else 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except USER_ERRORS as error:
        name = node.get_name() if node is not None else getattr(factory, "NODE_NAME", "node")
        rclpy.logging.get_logger(name).error(str(error))
        return 2
    except Exception:
        if not rclpy.ok():  # Ctrl-C or SIGTERM while the node was being set up
            return 0
        raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
