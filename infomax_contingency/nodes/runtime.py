"""The body of every node's ``main()``: ROS argument parsing, spinning, clean shutdown.

:func:`run_node` spins the node until it is done or interrupted (Ctrl-C, SIGTERM) and
ends with ``rclpy.try_shutdown()``; :func:`run_nodes` does the same for several nodes in
one process (``bringup``). Neither leaks memory per callback (:func:`spin_until_done`).

A node process started by another process that must not outlive it (the demo, the test
harness: :data:`PARENT_PID_VARIABLE` names that parent) ends when the parent dies, for any
reason, SIGKILL included (:func:`end_with_parent`).
"""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, MutableMapping, Sequence
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from infomax_contingency.errors import USER_ERRORS
from infomax_contingency.lifetime import (
    process_alive,
    signal_when_parent_dies,
    stop_came_while_starting,
)
from infomax_contingency.nodes.parameter_files import (
    params_files,
    undeclared_command_line_parameters,
    undeclared_parameters,
)

SPIN_TIMEOUT_S = 0.1
"""Seconds one executor wait may block, so that a finished node is noticed."""


def _ros_argument_error(message: str) -> str:
    """The one-line explanation of an ``rclpy.init`` failure."""
    reason = message.split(", at ")[0].removeprefix("failed to initialize rcl: ")
    if "Couldn't parse params file" in reason:
        path = reason.split("'--params-file ", 1)[-1].split("'", 1)[0]
        detail = reason.split("Error: ", 1)[-1]
        if "Error opening YAML file" in detail:
            return f"cannot read the parameter file {path}: no such file, or not readable"
        return f"the parameter file {path} is not a valid ROS parameter file: {detail}"
    if "parameter override rule" in reason:
        return (
            f"{reason} (a parameter is given as `-p name:=value`, or `-p node_name:name:=value`"
            " to override a value that a --params-file sets; the value must not be empty)"
        )
    return reason


def init_ros(args: Sequence[str] | None, program: str) -> bool:
    """``rclpy.init``; malformed ``--ros-args`` give one line on stderr and False.

    rclpy's own signal handlers are not installed: :class:`StopSignals` handles Ctrl-C and
    SIGTERM, so that no KeyboardInterrupt can surface in the middle of a callback or of
    the shutdown.
    """
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except rclpy_implementation.RCLError as error:
        print(f"{program}: invalid ROS arguments: {_ros_argument_error(str(error))}",
              file=sys.stderr)
        return False
    return True


PARENT_PID_VARIABLE = "INFOMAX_CONTINGENCY_PARENT_PID"
"""Environment variable by which a process that starts nodes (the demo, the test harness)
names itself: the node then ends with it (:func:`end_with_parent`)."""

def end_with_parent(environ: MutableMapping[str, str] = os.environ) -> bool:
    """Get SIGTERM when the parent named by :data:`PARENT_PID_VARIABLE` dies; False if it has.

    Without the variable (a node started by hand, by ``ros2 run`` or a launch that does
    not set it) nothing changes and the result is True. With it, the kernel sends this
    process SIGTERM (:class:`StopSignals`: a clean stop) when its parent dies, however
    it dies (Linux ``prctl(PR_SET_PDEATHSIG)``; the parent is the thread that started
    this process, which for the demo and the harness is their main thread). The signal is
    set before the parent is checked, so a parent that died before (while this process
    was still loading: it then has another parent) is seen here, and one that dies after
    sends the signal. A wrapper between the two (``ros2 run`` starts the executable as
    its child) is this process's parent then, and the named process must be alive. The
    variable is removed, so that no process this one starts takes it for its own parent.

    Returns False when the parent is already gone: the caller ends at once.
    """
    text = environ.pop(PARENT_PID_VARIABLE, "").strip()
    if not text.isdigit():
        return True
    signal_when_parent_dies(signal.SIGTERM)
    parent = int(text)
    return os.getppid() == parent or process_alive(parent)


def parent_pid_environment(environ: MutableMapping[str, str]) -> MutableMapping[str, str]:
    """``environ`` naming this process as the parent its node processes end with."""
    environ[PARENT_PID_VARIABLE] = str(os.getpid())
    return environ


STOP_DEADLINE_S = 20.0
"""Seconds after a stop signal by which a node process has ended, whatever hangs: the stop
itself takes at most :data:`STOP_BUDGET_S` and the teardown about a second more; a
process still there (a DDS teardown stuck on a loaded machine, a parent's SIGKILL that
left it alone) then ends at once, with one line and status 1, rather than run on."""

START_DEADLINE_S = 60.0
"""Seconds from a node process's start (its main taking the signals) to its nodes spinning,
whatever hangs: a start (rclpy.init, node creation, the libraries a node loads then) takes
a few seconds at most here, even with a launch's six nodes starting at once on a loaded
machine, and the rest is a slower robot computer's margin; one still not spinning (stuck
in node creation: Fast DDS's participant creation has known hangs, docs/ENVIRONMENT.md)
ends at once, with one line and status 1, so that its launch ends naming it (or a
``respawn`` starts it again) rather than wait on it for ever."""

DEADLINE_POLL_S = 0.5
"""Seconds between two looks of the deadlines' watchdog at whether one passed."""

HARD_DEADLINE_MARGIN_S = 5.0
"""Seconds after the stop deadline at which a process whose main thread holds the
interpreter (a C call stuck in DDS's teardown: the deadline's own thread then never runs)
is ended by :mod:`faulthandler`'s thread, which needs no interpreter: the stacks of its
threads on stderr (where it hung), then status 1."""


def _end_now(program: str, deadline_s: float) -> None:
    """The stop deadline passed: one line on stderr, then end without any more teardown."""
    try:
        sys.stderr.write(f"{program}: not stopped {deadline_s:g} s after the stop signal;"
                         " ending now\n")  # fmt: skip
        sys.stderr.flush()
    finally:
        os._exit(1)


def _not_started(program: str, deadline_s: float) -> None:
    """The start deadline passed: one line on stderr, then end without any teardown."""
    try:
        sys.stderr.write(f"{program}: not started within {deadline_s:g} s (creating its node"
                         " did not return: the middleware may be stuck, docs/ENVIRONMENT.md);"
                         " ending now\n")  # fmt: skip
        sys.stderr.flush()
    finally:
        os._exit(1)


_NO_STDERR: list[Any] = []
"""Where the hard deadline writes the stacks of a process without a standard error (kept
open: faulthandler holds only its file descriptor)."""


def _arm_hard_deadline(seconds: float) -> None:
    """End the process ``seconds`` from now, even if no Python code can run by then.

    One such deadline at a time: a later call replaces the earlier one; a negative
    ``seconds`` cancels it. The threads' stacks go to standard error, or nowhere in a
    process started with it closed (which still ends).
    """
    if seconds < 0:
        faulthandler.cancel_dump_traceback_later()
        return
    try:
        faulthandler.dump_traceback_later(seconds, exit=True)
    except (RuntimeError, ValueError, AttributeError):  # sys.stderr None or closed
        if not _NO_STDERR:
            _NO_STDERR.append(open(os.devnull, "w"))  # open while the process runs
        faulthandler.dump_traceback_later(seconds, exit=True, file=_NO_STDERR[0])


class StopSignals:
    """Ctrl-C (SIGINT) and SIGTERM ask the spin loop to stop; nothing is raised.

    The Python-level handler only sets :attr:`requested`; the spin loop looks at it after
    every executor wait (at most :data:`SPIN_TIMEOUT_S`), so a signal never interrupts a
    callback, a second one during the shutdown changes nothing, and the process ends with
    status 0 after destroying its nodes.

    :meth:`install` also starts a watchdog thread (daemon) for two deadlines. The start
    deadline: a process whose nodes are not spinning (:meth:`spinning`) ``start_deadline_s``
    (:data:`START_DEADLINE_S`) after :meth:`install`, and that was not asked to stop, is
    ended by ``on_start_deadline`` (:func:`_not_started`); a stop signal during the start
    hands it to the stop deadline. The stop deadline: once a stop
    began (a signal, or :meth:`arm_stop_deadline` when the node finished), a process that
    has not ended ``deadline_s`` (:data:`STOP_DEADLINE_S`) later is ended by
    ``on_deadline`` (:func:`_end_now`). A process whose main thread holds the interpreter,
    so that the watchdog cannot run, is ended :data:`HARD_DEADLINE_MARGIN_S` after either
    by :mod:`faulthandler`. The thread is started here, never from the signal handler or
    while the interpreter shuts down; the handler only sets flags.

    Args:
        program: the process's name in the deadlines' lines.
        deadline_s: seconds from the stop to ``on_deadline``.
        on_deadline: ends the process: ``(program, deadline_s)``.
        arm_hard_deadline: ends the process ``seconds`` from now without the interpreter
            (a later call replaces an earlier one; a negative ``seconds`` cancels it).
        start_deadline_s: seconds from :meth:`install` to ``on_start_deadline`` (None:
            :data:`START_DEADLINE_S` as it is when the instance is made).
        on_start_deadline: ends the process: ``(program, start_deadline_s)`` (None:
            :func:`_not_started` as it is when the instance is made).
    """

    def __init__(self, program: str = "node", deadline_s: float = STOP_DEADLINE_S,
                 on_deadline: Callable[[str, float], None] = _end_now,
                 arm_hard_deadline: Callable[[float], None] = _arm_hard_deadline,
                 start_deadline_s: float | None = None,
                 on_start_deadline: Callable[[str, float], None] | None = None) -> None:
        self.requested = False
        self.stopping_since: float | None = None
        """``time.monotonic()`` when the stop began (None: running)."""
        self.starting_since: float | None = None
        """``time.monotonic()`` when :meth:`install` was called (None: spinning, or not yet)."""
        self._previous: dict[int, Any] = {}
        self._program = program
        self._deadline_s = deadline_s
        self._on_deadline = on_deadline
        self._arm_hard_deadline = arm_hard_deadline
        self._hard_deadline_armed = False
        self._arming = threading.Lock()  # the watchdog may arm the stop's, beside the main thread
        self._start_deadline_s = START_DEADLINE_S if start_deadline_s is None else start_deadline_s
        self._on_start_deadline = _not_started if on_start_deadline is None else on_start_deadline
        self._watchdog = threading.Thread(target=self._watch, name="deadlines", daemon=True)

    def _watch(self) -> None:
        while True:
            starting_since = self.starting_since
            if self.stopping_since is not None and starting_since is not None:
                self.arm_stop_deadline()  # a stop while starting: the start's hard one goes
            now = time.monotonic()
            if self.stopping_since is not None and now - self.stopping_since >= self._deadline_s:
                faulthandler.cancel_dump_traceback_later()  # this thread runs: it ends it
                self._on_deadline(self._program, self._deadline_s)
                return
            if (self.stopping_since is None and starting_since is not None
                    and now - starting_since >= self._start_deadline_s):  # fmt: skip
                faulthandler.cancel_dump_traceback_later()
                self._on_start_deadline(self._program, self._start_deadline_s)
                return
            time.sleep(DEADLINE_POLL_S)

    def install(self) -> StopSignals:
        """Take over SIGINT and SIGTERM (main thread only; elsewhere a no-op); the watchdog.

        The start deadline begins: :meth:`spinning` ends it.
        """
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                self._previous[signum] = signal.signal(signum, self._handle)
            except ValueError:  # not the main thread
                pass
        if stop_came_while_starting():  # a stop that came before, its exit lost
            self._handle(signal.SIGINT, None)
        if self.stopping_since is None and self.starting_since is None:
            self.starting_since = time.monotonic()
            self._arm_hard_deadline(self._start_deadline_s + HARD_DEADLINE_MARGIN_S)
        if not self._watchdog.is_alive():
            self._watchdog.start()
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        self.requested = True
        if self.stopping_since is None:
            self.stopping_since = time.monotonic()

    def spinning(self) -> None:
        """The nodes were created and spin now: the start deadline no longer applies."""
        with self._arming:
            if self.starting_since is not None and not self._hard_deadline_armed:
                self._arm_hard_deadline(-1.0)
            self.starting_since = None

    def arm_stop_deadline(self) -> None:
        """The process is stopping (a signal, or its node finished): it ends by the deadline.

        Called by the spin loop's caller once it stopped spinning, before any teardown:
        this also arms the deadline that needs no interpreter (:data:`HARD_DEADLINE_MARGIN_S`).
        """
        if self.stopping_since is None:
            self.stopping_since = time.monotonic()
        with self._arming:
            if not self._hard_deadline_armed:
                self._hard_deadline_armed = True
                left_s = self._deadline_s - (time.monotonic() - self.stopping_since)
                self._arm_hard_deadline(max(left_s, 0.0) + HARD_DEADLINE_MARGIN_S)

    def restore(self) -> None:
        """Give the signals back to their previous handlers; no start deadline any more."""
        self.spinning()
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def ignore_from_now_on(self) -> None:
        """Ignore SIGINT and SIGTERM: the process is ending.

        ``ros2 launch`` sends them again on a second Ctrl-C; one must not raise a
        KeyboardInterrupt while the interpreter shuts down.
        """
        for signum in self._previous:
            signal.signal(signum, signal.SIG_IGN)
        self._previous.clear()


def spin_until_done(executor: Executor, done: Future, stop: StopSignals | None = None) -> None:
    """Spin ``executor`` until ``done`` completes, ``stop`` is requested or ROS shuts down.

    Not ``spin_until_future_complete``: rclpy 7.1's version of it adds a done-callback to
    the future on every spin, so memory grows with every callback handled while the
    future is pending (a node that runs for days). This loop adds nothing per spin.
    """
    while rclpy.ok() and not done.done() and not (stop is not None and stop.requested):
        executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)


REPAIR_WAIT_S = 3.5
"""Seconds a reliable sample lost on the way may take to be resent. Fast DDS (Jazzy)
resends a sample a reader missed (a busy recorder's transport queue overflowed) when
the reader answers the writer's heartbeat, and a writer of small messages (a Bool per
step) sends one only every 3 s; a reader holds every later sample of that writer until
the repair (delivery is in order). So a stop that ends sooner can lose the last seconds
of a topic, however reliable."""

STOP_BUDGET_S = REPAIR_WAIT_S + 1.5
"""At most this long, after a stop, for a process's acknowledgment wait and drain together
(:func:`await_acknowledgments`, then :func:`drain_queued_messages`); the process then
ends within about a second more (well before a launcher's SIGKILL)."""

DRAIN_BUDGET_S = STOP_BUDGET_S
"""At most this long for nodes that keep a record to take what is queued: while other
nodes still publish the recorded topics, a repair may still come."""

SHARED_TOPICS = frozenset({"/diagnostics"})
"""Topics every node on the domain publishes (other robots' too, outside any namespace):
a drain does not wait for their publishers to go."""

DRAIN_IDLE_SPINS = 3
"""The queues count as empty after this many spins in a row that took no message."""


def drain_queued_messages(executor: Executor, nodes: Sequence[Node],
                          budget_s: float = DRAIN_BUDGET_S) -> None:  # fmt: skip
    """Spin until the nodes that keep a record have taken every message sent to them.

    Such nodes (the recorder) have ``messages_taken() -> int``. On a stop, their DDS
    queues may still hold messages that arrived in a burst (a lockstep graph makes 40
    steps in 0.1 s; the executor serves one subscription at a time), and a sample lost
    on the way comes only with its writer's next heartbeat (:data:`REPAIR_WAIT_S`):
    without this they would be lost. So the spin goes on until the queues are empty and
    no node of another process publishes a recorded topic any more (the graph stopped
    too: each of its nodes first waits until its readers acknowledged everything,
    :func:`await_acknowledgments`), or ``budget_s`` seconds passed. The nodes of this
    process (``bringup``) deliver in-process: nothing of theirs is waited for.
    """
    keepers = [node for node in nodes if callable(getattr(node, "messages_taken", None))]
    if not keepers:
        return
    for node in nodes:  # the others stop acting now (a room in lockstep would go on)
        if node not in keepers:
            executor.remove_node(node)
    local = {node.get_fully_qualified_name() for node in nodes}
    deadline = time.monotonic() + budget_s
    idle = 0
    while time.monotonic() < deadline and rclpy.ok():
        if idle >= DRAIN_IDLE_SPINS and not any(_others_publish(node, local) for node in keepers):
            return
        before = sum(node.messages_taken() for node in keepers)
        executor.spin_once(timeout_sec=0.02)
        idle = idle + 1 if sum(node.messages_taken() for node in keepers) == before else 0


def _others_publish(node: Node, local: set[str]) -> bool:
    """True while a node of another process publishes a topic ``node`` subscribes to.

    ``local``: the fully qualified names of this process's nodes (they are stopping).
    Topics of :data:`SHARED_TOPICS` do not count.
    """
    for subscription in node.subscriptions:
        if subscription.topic_name in SHARED_TOPICS:
            continue
        for info in node.get_publishers_info_by_topic(subscription.topic_name):
            name = f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            if name not in local:
                return True
    return False


ACK_BUDGET_S = REPAIR_WAIT_S + 0.5
"""At most this long, on a stop, for the readers to acknowledge what was published."""


def await_acknowledgments(nodes: Sequence[Node], budget_s: float = ACK_BUDGET_S) -> None:
    """Wait until every reliable publisher's messages are acknowledged (at most ``budget_s``).

    A reliable writer that is destroyed before its readers acknowledged its last messages
    takes them with it: a reader that had dropped a packet in a burst (a recorder busy
    with 20 windows of audio) can no longer have it repaired, and the repair comes only
    with the writer's next heartbeat (:data:`REPAIR_WAIT_S`). Each writer is waited for
    in turn, within one budget; with everything acknowledged this returns at once.
    """
    deadline = time.monotonic() + budget_s
    for node in nodes:
        for publisher in list(node.publishers):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            try:
                publisher.wait_for_all_acked(Duration(nanoseconds=int(remaining * 1e9)))
            except Exception:  # a publisher already destroyed, or the context gone
                continue


def warn_undeclared_parameters(nodes: Sequence[Node], program: str, args: Sequence[str]
                               ) -> None:  # fmt: skip
    """Warn about the keys of the ``--params-file`` files and ``-p`` in ``args`` no node takes.

    rcl ignores them silently (a misspelled key or node section): each is named once, by
    the node it was meant for, or by ``program`` for a section that matches no node.
    """
    for node, message in undeclared_parameters(params_files(args), nodes):
        logger = node.get_logger() if node is not None else rclpy.logging.get_logger(program)
        logger.warning(message)
    for node, message in undeclared_command_line_parameters(args, nodes):
        node.get_logger().warning(message)


def first_to_finish(nodes: Sequence[Node]) -> Future:
    """A future done with the exit status of the first of ``nodes`` that finishes."""
    any_finished = Future()
    for node in nodes:
        finished = getattr(node, "finished", None)
        if finished is not None:
            finished.add_done_callback(
                lambda f: any_finished.done() or any_finished.set_result(f.result())
            )
    return any_finished


OUT_OF_MEMORY = ("out of memory: an input (a file, a parameter) needs more memory than this"
                 " process may use (docs/LIMITS.md)")
"""A node's error line for a MemoryError (one line, not a traceback)."""


def _start_error(error: Exception) -> str:
    """The one line of a node that cannot start: a user error, a size, a parameter's type.

    MemoryError: a size no check foresaw. rclpy refuses a value of the wrong type for a
    parameter every node has (``-p use_sim_time:=1``) before the node's own checks.
    """
    if isinstance(error, MemoryError):
        return OUT_OF_MEMORY
    if isinstance(error, InvalidParameterTypeException):
        return str(error).rsplit(": ", 1)[0].replace("Trying to set", "cannot set")
    return str(error)


def run_nodes(factories: Sequence[tuple[str, Callable[[], Node]]], program: str,  # noqa: C901
              args: Sequence[str] | None = None) -> int:
    """Create the nodes, spin them on one executor until one finishes; the exit status.

    A node that fails to start on bad parameters or another user error is named in one
    error line (status 2); Ctrl-C and SIGTERM end the process cleanly (status 0), also
    when they arrive again during shutdown; no traceback either way. A process's main:
    it ends by :data:`STOP_DEADLINE_S` after its nodes stop.
    """
    stop = StopSignals(program).install()
    if not end_with_parent():
        print(f"{program}: the process that started it is gone; not starting", file=sys.stderr)
        stop.restore()
        return 0
    if not init_ros(args, program):
        stop.restore()
        return 2
    executor = SingleThreadedExecutor()
    nodes: list[Node] = []
    current = program
    try:
        for name, factory in factories:
            current = name  # named in the error line if it cannot start
            nodes.append(factory())
            executor.add_node(nodes[-1])
        current = program
        warn_undeclared_parameters(nodes, program, sys.argv if args is None else args)
        any_finished = first_to_finish(nodes)
        stop.spinning()
        spin_until_done(executor, any_finished, stop)
        stop.arm_stop_deadline()
        stop_by = time.monotonic() + STOP_BUDGET_S
        await_acknowledgments(nodes, min(ACK_BUDGET_S, STOP_BUDGET_S))
        drain_queued_messages(executor, nodes, max(0.0, stop_by - time.monotonic()))
        return int(any_finished.result()) if any_finished.done() else 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except (*USER_ERRORS, MemoryError, InvalidParameterTypeException) as error:
        if stop.requested or not rclpy.ok():  # a signal while a node was being set up
            return 0
        rclpy.logging.get_logger(current).error(_start_error(error))
        return 2
    except Exception:
        if stop.requested or not rclpy.ok():  # a signal in the middle of the set-up
            return 0
        raise
    finally:
        stop.arm_stop_deadline()  # whatever ended the spin: the teardown ends by the deadline
        for node in nodes:
            try:
                node.destroy_node()
            except Exception:  # the context may already be gone
                pass
        executor.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown()
        stop.ignore_from_now_on()


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until it finishes or is interrupted; return the exit status.

    Bad parameters and other user errors are logged as one error line (status 2);
    Ctrl-C and SIGTERM end the node cleanly (status 0).
    """
    name = getattr(factory, "NODE_NAME", "node")
    return run_nodes([(name, factory)], name, args)
