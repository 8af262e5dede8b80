"""End to end: the whole graph (processes, real DDS) against the simulated room, in lockstep.

The fake room is deterministic for a seed and the graph runs in lockstep, so each run's
bits, decisions and beliefs are reproducible; assertions are on step numbers.
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Callable

import numpy as np
import pytest
from std_srvs.srv import Trigger

from graph_harness import FIXED_THRESHOLD, Graph, graph_fixture, room_nodes
from infomax_contingency.audio.binarizer import Binarizer
from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.model import ModelParams, StatisticTracker
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.fake_room import FakeRoom, FakeRoomConfig, simulate_audio_loop

make_graph = graph_fixture()
pytestmark = pytest.mark.slow


def postures(graph: Graph) -> list[str]:
    return [posture for _, posture in graph.recorder.posture]


def test_responsive_room_belief_passes_095_and_posture_turns_attentive(
    make_graph: Callable[[], Graph],
) -> None:
    steps = 200
    graph = make_graph()
    graph.start(room_nodes({"room": "responsive", "seed": 1}, steps), "fake_audio_node")
    graph.wait_steps(steps)
    rec = graph.recorder
    beliefs = np.array(rec.belief[:steps])
    assert beliefs.max() > 0.95, f"belief peaked at {beliefs.max():.3f} in {steps} steps"
    first = int(np.argmax(beliefs > 0.95)) + 1
    assert first < steps
    graph.wait(lambda: rec.current_posture == "attentive", "the attentive posture")
    assert postures(graph)[0] == "bored"
    assert all(rec.partner_present[:steps])
    assert sum(rec.vocalize[:steps]) >= 5


@pytest.mark.parametrize("room", ["silent", "noisy"])
def test_rooms_without_partner_keep_belief_low_and_posture_bored(
    make_graph: Callable[[], Graph], room: str
) -> None:
    steps = 200
    graph = make_graph()
    graph.start(room_nodes({"room": room, "seed": 1}, steps), "fake_audio_node")
    graph.wait_steps(steps)
    rec = graph.recorder
    beliefs = np.array(rec.belief[:steps])
    assert beliefs.max() < 0.05, f"belief reached {beliefs.max():.3f}"
    assert sum(rec.vocalize[:steps]) >= 5, "the robot must have asked"
    assert not any(rec.partner_present[:steps])
    if room == "noisy":
        assert 0.2 < np.mean(rec.sound[:steps]) < 0.9, "the noisy room must be noisy"
    assert set(postures(graph)) == {"bored"}


def test_partner_who_leaves_is_noticed_with_bounded_memory(
    make_graph: Callable[[], Graph],
) -> None:
    steps, leave_step = 300, 150  # the partner leaves after 75 s of room time
    room = {"room": "responsive", "seed": 1, "partner_leave_s": leave_step * 0.5}
    graph = make_graph()
    graph.start(room_nodes(room, steps, memory_steps=60), "fake_audio_node")
    graph.wait_steps(steps)
    rec = graph.recorder
    beliefs = np.array(rec.belief[:steps])
    assert rec.partner_present[leave_step - 1] and not rec.partner_present[leave_step]
    assert beliefs[:leave_step].max() > 0.95
    assert beliefs[-50:].max() < 0.2, f"belief still {beliefs[-50:].max():.3f} at the end"
    graph.wait(lambda: rec.current_posture == "bored" and len(rec.posture) >= 3, "bored again")
    assert postures(graph) == ["bored", "attentive", "bored"]
    attentive_at, bored_at = rec.posture[1][0], rec.posture[2][0]
    assert attentive_at <= leave_step < bored_at


def _offline(seed: int, steps: int) -> list:
    params = ModelParams.named("robot")
    table = PolicyTable.load(
        resource_path("policies", "robot_receding_H24_M60.npz"), expected_params=params
    )
    room = FakeRoom(FakeRoomConfig.preset("responsive"), seed)
    binarizer = Binarizer(FIXED_THRESHOLD["threshold_db"])
    return simulate_audio_loop(PolicyController(table), room, binarizer, steps)


def test_same_seed_twice_gives_the_same_run_as_offline(make_graph: Callable[[], Graph]) -> None:
    steps, seed = 150, 7
    runs = []
    for _ in range(2):
        graph = make_graph()
        graph.start(room_nodes({"room": "responsive", "seed": seed}, steps), "fake_audio_node")
        graph.wait_steps(steps)
        rec = graph.recorder
        runs.append((rec.sound[:steps], rec.vocalize[:steps], rec.belief[:steps]))
        graph.close()
    assert runs[0] == runs[1]
    offline = _offline(seed, steps)
    bits, decisions, beliefs = runs[0]
    assert bits == [bool(r.y) for r in offline]
    assert decisions == [bool(r.u) for r in offline]
    assert beliefs == [r.belief for r in offline]
    assert 0 < sum(bits) < steps and 0 < sum(decisions) < steps


def test_belief_node_killed_and_restarted_publishes_again(
    make_graph: Callable[[], Graph],
) -> None:
    graph = make_graph()
    graph.start(room_nodes({"room": "responsive", "seed": 3}, 50_000), "fake_audio_node")
    rec = graph.recorder
    graph.wait_steps(100)
    assert graph.processes.stop("belief_node") == 0
    with rec.lock:
        stopped_at, sounds_then = len(rec.belief), len(rec.sound)
    graph.wait(lambda: len(rec.sound) > sounds_then + 50, "the graph to go on without it")
    graph.processes.start("belief_node", {"memory_steps": 0})
    graph.wait(lambda: len(rec.belief) >= stopped_at + 20, "beliefs from the restarted node")
    assert all(0.0 <= b <= 1.0 for b in rec.belief[stopped_at:])

    # From a reset on, the new node's beliefs are an offline run of the statistic over
    # the bits and decisions of the steps since the reset: it pairs them correctly.
    client = rec.create_client(Trigger, "/belief_node/reset")
    assert client.wait_for_service(timeout_sec=60.0)
    before_ns = time.time_ns()
    future = client.call_async(Trigger.Request())
    graph.wait(future.done, "the reset service")
    after_ns = time.time_ns()
    assert future.result().success
    graph.wait(
        lambda: sum(stamp > after_ns for _, stamp in rec.times["belief"][-60:]) == 60,
        "60 beliefs after the reset",
    )
    with rec.lock:
        bits, decisions = list(rec.sound), list(rec.vocalize)
        beliefs, stamps = list(rec.belief), [stamp for _, stamp in rec.times["belief"]]
        sound_stamps = [stamp for _, stamp in rec.times["sound"]]
    graph.processes.stop("fake_audio_node")
    params = ModelParams.named("robot")

    def offline(k: int, n: int) -> list[float]:
        tracker, out = StatisticTracker(params), []
        for y, u in zip(bits[k : k + n], decisions[k : k + n], strict=True):
            out.append(tracker.observe(y).belief(params))
            tracker.act(u)
        return out

    around = range(
        bisect.bisect_left(stamps, before_ns) - 5, bisect.bisect_right(stamps, after_ns) + 5
    )
    # The restarted node may lag behind the graph (it worked through a backlog first).
    n, last = 40, bisect.bisect_right(sound_stamps, after_ns) + 5
    runs = {
        k: offline(k, n)
        for k in range(max(0, last - 1000), min(last, min(len(bits), len(decisions)) - n + 1))
    }
    matches = [(j, k) for j in around for k, run in runs.items() if beliefs[j : j + n] == run]
    assert matches, "no run of beliefs after the reset equals the offline statistic"
