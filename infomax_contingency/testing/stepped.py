"""Nodes in the test's own process, on one executor that the test steps by hand.

The fast, deterministic way to test nodes and the lockstep graph: no child processes and
no background spin thread. :class:`SteppedExecutor` handles callbacks only when the test
asks (:meth:`SteppedExecutor.run_until` spins until a condition on the recorded messages
holds), so a test reads its state between steps without locks or sleeps. Messages still
travel over real DDS (on loopback) between the nodes. The deadline of ``run_until``
guards against a hang; it never paces anything.

:class:`Probe` is the one helper node of the tests: it publishes to the node under test
and records what that node publishes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

import rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile

from infomax_contingency.nodes.qos import STREAM_QOS
from infomax_contingency.testing.graph import instrument_options

DEFAULT_DEADLINE_S = 60.0
"""Seconds a condition may take before the test fails (a guard, not a pace)."""


class StepTimeoutError(AssertionError):
    """A condition did not hold before the deadline; the message says which."""


class Probe(Node):
    """Publishes to and records from the nodes under test.

    A test's instrument (:func:`~infomax_contingency.testing.graph.instrument_options`): no
    services, and no default QoS event handlers on what it publishes or subscribes.

    Args:
        name: node name (several probes need distinct names).
    """

    def __init__(self, name: str = "probe", **kwargs: Any) -> None:
        super().__init__(name, **instrument_options(**kwargs))
        self.received: dict[str, list[Any]] = {}
        self.pubs: dict[str, Any] = {}

    def listen(
        self,
        topic: str,
        kind: type,
        qos: QoSProfile | int = STREAM_QOS,
        then: Callable[[Any], None] | None = None,
    ) -> list[Any]:
        """Record every message on ``topic``; returns the list it grows.

        ``then(message)``, if given, runs after each message is recorded (e.g. to answer).
        """
        received: list[Any] = []
        self.received[topic] = received

        def record(message: Any) -> None:
            received.append(message)
            if then is not None:
                then(message)

        events = SubscriptionEventCallbacks(use_default_callbacks=False)
        self.create_subscription(kind, topic, record, qos, event_callbacks=events)
        return received

    def talk(self, topic: str, kind: type, qos: QoSProfile = STREAM_QOS) -> Any:
        """A publisher on ``topic``."""
        events = PublisherEventCallbacks(use_default_callbacks=False)
        self.pubs[topic] = self.create_publisher(kind, topic, qos, event_callbacks=events)
        return self.pubs[topic]


class SteppedExecutor:
    """One executor for the nodes of a test, spun only inside :meth:`run_until`."""

    def __init__(self, nodes: Iterable[Node] = ()) -> None:
        self.executor = SingleThreadedExecutor()
        self.nodes: list[Node] = []
        for node in nodes:
            self.add(node)

    def add(self, node: Node) -> Node:
        """Put ``node`` on the executor; returns it."""
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def remove(self, node: Node) -> None:
        """Take ``node`` off the executor and destroy it (as if its process stopped)."""
        self.executor.remove_node(node)
        self.nodes.remove(node)
        node.destroy_node()

    def run_until(
        self,
        condition: Callable[[], bool],
        what: str = "the condition",
        deadline_s: float = DEFAULT_DEADLINE_S,
    ) -> None:
        """Handle callbacks until ``condition()`` holds.

        Raises:
            StepTimeoutError: it did not hold within ``deadline_s`` seconds.
        """
        deadline = time.monotonic() + deadline_s
        while not condition():
            if time.monotonic() > deadline:
                raise StepTimeoutError(f"{what} did not happen within {deadline_s:g} s")
            self.executor.spin_once(timeout_sec=0.05)

    def run_for_callbacks(self, count: int) -> None:
        """Handle up to ``count`` ready callbacks without waiting.

        Shows that nothing more happens, e.g. that a lockstep node holds its next window.
        """
        for _ in range(count):
            self.executor.spin_once(timeout_sec=0.0)

    def connected(self, publisher: Any, subscribers: int = 1, what: str = "") -> None:
        """Step until ``publisher`` is matched with ``subscribers`` subscriptions."""
        self.run_until(
            lambda: publisher.get_subscription_count() >= subscribers,
            what or f"{subscribers} subscriber(s) on {publisher.topic_name}",
        )

    def close(self) -> None:
        """Destroy the nodes and the executor."""
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)


@contextmanager
def nodes_on_their_own_executors() -> Iterator[Callable[..., tuple[Any, Probe, SteppedExecutor]]]:
    """``start(NodeClass, **parameters)`` -> (node, its probe, their stepped executor).

    Initialises rclpy; on leaving, closes every executor started and shuts rclpy down.
    The parameters are given to the node as overrides (as ``-p name:=value`` would).
    """
    rclpy.init()
    executors: list[SteppedExecutor] = []

    def start(node_class: type, **parameters: Any) -> tuple[Any, Probe, SteppedExecutor]:
        overrides = [Parameter(name, value=value) for name, value in parameters.items()]
        node = node_class(parameter_overrides=overrides)
        probe = Probe()
        executors.append(SteppedExecutor([node, probe]))
        return node, probe, executors[-1]

    try:
        yield start
    finally:
        for executor in executors:
            executor.close()
        rclpy.try_shutdown()
