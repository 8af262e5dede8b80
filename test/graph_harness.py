"""Helpers for the tests that run the node graph as real processes over DDS.

The ``make_graph`` fixture (``make_graph = graph_fixture()`` in a test module) makes
:class:`Graph` objects: node processes plus a recorder node in the test process; the
processes are stopped (SIGINT, then SIGTERM, then SIGKILL) and the
recorder destroyed after the test, whatever happens. Assertions are on step counts,
never on wall time; the timeouts are generous so a loaded machine only makes tests slow.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy

from infomax_contingency.audio.bag import read_topics
from infomax_contingency.testing.graph import (
    GraphProcesses,
    SpinThread,
    StepRecorder,
    start_graph,
    wait_until,
)

STEP_TIMEOUT_S = 120.0
"""Seconds a graph may take to come up and run its steps before a test fails."""

FIXED_THRESHOLD = {"threshold_mode": "fixed", "threshold_db": -40.0}
"""The mic's threshold for the fake room (its floor is -60 dB, its sounds above -35 dB)."""


class Graph:
    """Node processes and a recorder of their topics."""

    def __init__(self, workdir: Path) -> None:
        self.processes = GraphProcesses(workdir)
        self.recorder = StepRecorder(instrument=True)
        self._spin = SpinThread(self.recorder)
        self._spin.__enter__()

    def start(self, nodes: dict[str, dict[str, Any]], clock: str) -> None:
        """Start the nodes, the clock node last."""
        start_graph(self.processes, self.recorder, nodes, clock, timeout_s=STEP_TIMEOUT_S)

    def wait(self, condition: Callable[[], bool], what: str) -> None:
        """Wait for ``condition``; fail with the nodes' state if it does not come."""
        if not wait_until(condition, STEP_TIMEOUT_S, self.processes):
            pytest.fail(
                f"timed out waiting for {what}; received {self.recorder.counts()}\n"
                f"{self.processes.report()}"
            )

    def wait_steps(self, steps: int) -> None:
        """Wait until ``steps`` bits, decisions and beliefs have been recorded."""
        rec = self.recorder
        self.wait(
            lambda: min(len(rec.sound), len(rec.vocalize), len(rec.belief)) >= steps,
            f"{steps} steps",
        )

    def close(self) -> None:
        """Stop the nodes and the recorder."""
        try:
            self.processes.stop_all()
        finally:
            self._spin.__exit__(None, None, None)
            self.recorder.destroy_node()


def room_nodes(
    room: dict[str, Any], steps: int, memory_steps: int = 0, listeners: int = 3,
    bit_source: dict[str, Any] | None = None,
) -> dict[str, dict[str, Any]]:
    """The graph against the fake room in lockstep (recorder included in the listeners).

    ``bit_source``: mic_node's bit source and its settings. By default ``energy`` at a
    fixed -40 dB, on purpose: every window gives a step (``steps`` windows are ``steps``
    steps) and which windows are active is known from the room's levels alone. ``{}``:
    mic_node's default (``background``), whose warm-up windows give no step (the room
    then makes more than ``steps`` windows: give ``max_windows`` in ``room``).
    """
    if bit_source is None:
        bit_source = {"bit_source": "energy", **FIXED_THRESHOLD}
    return {
        "mic_node": {"source": "topic", **bit_source, "wait_for_listeners": listeners},
        # mic, belief, room and the recorder hear every decision
        "controller_node": {"wait_for_listeners": listeners + 1},
        "belief_node": {"memory_steps": memory_steps},
        "posture_node": {},
        "fake_audio_node": {"max_windows": steps, **room, "wait_for_truth_listeners": 1},
    }


def graph_fixture() -> Callable:
    """Make the ``make_graph`` fixture of a test module (assign it to ``make_graph``).

    The fixture is a factory of graphs sharing one rclpy context; every graph is
    closed, and the context shut down, after the test.
    """

    @pytest.fixture
    def make_graph(tmp_path: Path) -> Iterator[Callable[[], Graph]]:
        rclpy.init()
        graphs: list[Graph] = []

        def make() -> Graph:
            graphs.append(Graph(tmp_path / f"graph{len(graphs)}"))
            return graphs[-1]

        try:
            yield make
        finally:
            for graph in graphs:
                graph.close()
            rclpy.try_shutdown()

    return make_graph


STEP_TOPICS = ("/sound", "/sound_step", "/vocalize", "/vocalize_step", "/belief",
               "/partner_present")


def assert_every_step_recorded(bag: Path, steps: int, windows: int | None = None
                               ) -> dict[str, list]:  # fmt: skip
    """The bag holds ``steps`` messages of every step topic, from step 1; its topics.

    ``windows``: the room's windows, each with its truth (``partner_present``), when
    some gave no step (default: ``steps``).
    """
    topics = read_topics(bag, (*STEP_TOPICS, "/session_info"))
    for topic in STEP_TOPICS:
        expected = windows if windows is not None and topic == "/partner_present" else steps
        assert len(topics[topic]) == expected, (topic, len(topics[topic]))
    assert [int(m.data[1]) for _, m in topics["/sound_step"]] == list(range(1, steps + 1))
    assert len(topics["/session_info"]) == 1
    return topics
