"""End to end: the whole graph against the simulated room, in lockstep.

The nodes run in the test process on one hand-stepped executor (real DDS between them);
one smoke test runs them as separate processes and checks they compute the same run as
the offline loop. The fake room is deterministic for a seed and the graph runs in
lockstep, so each run's bits, decisions and beliefs are reproducible; assertions are on
step numbers.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from graph_harness import FIXED_THRESHOLD, Graph, graph_fixture, room_nodes
from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.core.controllers import PolicyController, default_check_in
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.posture import ATTENTIVE_ABOVE, BORED_BELOW
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.audio_loop import simulate_audio_loop
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig
from stepped_graph import SteppedGraph, stepped_graph

make_graph = graph_fixture()


def postures(graph: SteppedGraph | Graph) -> list[str]:
    return [posture for _, posture in graph.recorder.posture]


def test_responsive_room_belief_passes_095_and_posture_turns_attentive() -> None:
    steps = 200
    with stepped_graph(room_nodes({"room": "responsive", "seed": 1}, steps),
                       "fake_audio_node") as graph:  # fmt: skip
        graph.run_steps(steps)
        rec = graph.recorder
        beliefs = np.array(rec.belief[:steps])
        assert beliefs.max() > 0.95, f"belief peaked at {beliefs.max():.3f} in {steps} steps"
        first = int(np.argmax(beliefs > 0.95)) + 1
        assert first < steps
        graph.run_until(lambda: rec.current_posture == "attentive", "the attentive posture")
        assert postures(graph)[0] == "bored"
        assert all(rec.partner_present[:steps])
        assert sum(rec.vocalize[:steps]) >= 5


@pytest.mark.parametrize("room", ["silent", "noisy"])
def test_rooms_without_partner_keep_belief_low_and_posture_bored(room: str) -> None:
    steps = 200
    with stepped_graph(room_nodes({"room": room, "seed": 1}, steps), "fake_audio_node") as graph:
        graph.run_steps(steps)
        rec = graph.recorder
        graph.run_until(lambda: len(rec.partner_present) >= steps, f"{steps} truths")
        beliefs = np.array(rec.belief[:steps])
        # The robot's prior on K3 (mean 0.05) is that of mic_node's default source; the
        # fixed -40 dB threshold here holds the noisy room's K3 at 0.5, and the belief
        # rises for a few steps (0.37) before the background windows correct it.
        assert beliefs.max() < (0.05 if room == "silent" else 0.5), beliefs.max()
        assert beliefs[-1] < 0.01
        assert sum(rec.vocalize[:steps]) >= 5, "the robot must have asked"
        assert not any(rec.partner_present[:steps])
        if room == "noisy":
            assert 0.2 < np.mean(rec.sound[:steps]) < 0.9, "the noisy room must be noisy"
        graph.run_until(lambda: bool(rec.posture), "the first posture")
        assert set(postures(graph)) == {"bored"}


def test_partner_who_leaves_is_noticed_with_bounded_memory() -> None:
    steps, leave_step = 300, 150  # the partner leaves after 75 s of room time
    room = {"room": "responsive", "seed": 1, "partner_leave_s": leave_step * 0.5}
    with stepped_graph(room_nodes(room, steps, memory_steps=60), "fake_audio_node") as graph:
        graph.run_steps(steps)
        rec = graph.recorder
        graph.run_until(lambda: len(rec.partner_present) >= steps, f"{steps} truths")
        beliefs = np.array(rec.belief[:steps])
        assert rec.partner_present[leave_step - 1] and not rec.partner_present[leave_step]
        assert beliefs[:leave_step].max() > 0.95
        assert beliefs[-50:].max() < 0.2, f"belief still {beliefs[-50:].max():.3f} at the end"
        graph.run_until(lambda: rec.current_posture == "bored" and len(rec.posture) >= 3,
                        "bored again")  # fmt: skip
        assert postures(graph) == ["bored", "attentive", "bored"]
        attentive_at, bored_at = rec.posture[1][0], rec.posture[2][0]
        assert attentive_at <= leave_step < bored_at


def _offline(seed: int, steps: int, bit_source: str = "energy") -> list:
    """The offline loop's run (energy: the fixed threshold of :func:`room_nodes`)."""
    params = ModelParams.named("robot")
    table = PolicyTable.load(
        resource_path("policies", "robot_receding_H24_M60.npz"), expected_params=params
    )
    room = FakeRoom(FakeRoomConfig.preset("responsive"), seed)
    if bit_source == "energy":
        binarizer = make_bit_source("energy", 16000, 0.5, **FIXED_THRESHOLD)
    else:
        binarizer = make_bit_source(bit_source, 16000, 0.5)
        binarizer.follow_model(params)  # as mic_node does
    return simulate_audio_loop(PolicyController(table, params, default_check_in(params)), room,
                               binarizer, steps)  # fmt: skip


def _assert_equals_offline(run: tuple[list, list, list], offline: list, steps: int) -> None:
    bits, decisions, beliefs = run
    assert bits == [bool(r.y) for r in offline]
    assert decisions == [bool(r.u) for r in offline]
    assert beliefs == [r.belief for r in offline]
    assert 0 < sum(bits) < steps and 0 < sum(decisions) < steps


def test_same_seed_twice_gives_the_same_run_as_offline() -> None:
    steps, seed = 150, 7
    runs = []
    for _ in range(2):
        with stepped_graph(room_nodes({"room": "responsive", "seed": seed}, steps),
                           "fake_audio_node") as graph:  # fmt: skip
            graph.run_steps(steps)
            rec = graph.recorder
            runs.append((rec.sound[:steps], rec.vocalize[:steps], rec.belief[:steps]))
    assert runs[0] == runs[1]
    _assert_equals_offline(runs[0], _offline(seed, steps), steps)


def test_the_default_bit_source_in_the_lockstep_room_gives_the_offline_run() -> None:
    """mic_node's default source (background) in the lockstep room equals the offline loop.

    Its warm-up windows give no step (said on ``no_step``, on which the room goes on),
    then every window a bit; the offline loop skips the same windows, so bits,
    decisions, beliefs and truths are its own.
    """
    steps, seed = 150, 7
    room = {"room": "responsive", "seed": seed, "max_windows": 0}
    with stepped_graph(room_nodes(room, steps, bit_source={}), "fake_audio_node") as graph:
        graph.run_steps(steps)
        rec = graph.recorder
        windows = rec.step_windows(steps)
        graph.run_until(lambda: len(rec.partner_present) > windows[-1], "the steps' truths")
        run = (rec.sound[:steps], rec.vocalize[:steps], rec.belief[:steps])
        warmup = [window for _, window in rec.no_step]
        truths = [rec.partner_present[w] for w in windows]
        assert graph.nodes["fake_audio_node"].windows_without_step == len(warmup)
    # 8 background windows (warmup_s 4 s), then the threshold's delay of ta2 = 4 windows
    assert warmup == list(range(1, 13)) and windows[0] == 12
    assert windows == list(range(12, 12 + steps))
    offline = _offline(seed, steps, "background")
    _assert_equals_offline(run, offline, steps)
    assert truths == [r.partner_present for r in offline]


@pytest.mark.slow
def test_separate_processes_give_the_offline_run(make_graph: Callable[[], Graph]) -> None:
    """Smoke test: the same graph as node processes over DDS computes the offline run."""
    steps, seed = 100, 7
    graph = make_graph()
    graph.start(room_nodes({"room": "responsive", "seed": seed}, steps), "fake_audio_node")
    graph.wait_steps(steps)
    rec = graph.recorder
    run = (rec.sound[:steps], rec.vocalize[:steps], rec.belief[:steps])
    _assert_equals_offline(run, _offline(seed, steps), steps)


@pytest.mark.parametrize(
    ("room", "run", "binarizer"),
    [("office+partner", 0, "fixed"), ("quiet+leaving", 3, "fixed"),
     ("dog-home+partner", 0, "background"), ("laundry+leaving", 2, "background")],
)  # fmt: skip
def test_rooms_experiment_runs_equal_the_graph(room: str, run: int, binarizer: str) -> None:
    """Runs of ``experiment rooms`` equal the graph's (the pattern of the test above).

    A sample run (optimal table, belief memory 60; a fixed threshold, or mic_node's
    default source in a room held out later) gives the graph's bits, decisions, beliefs
    and postures.
    """
    from infomax_contingency.eval.rooms import controller_specs, room_seed, run_room
    from infomax_contingency.eval.rooms import postures as offline_postures

    params = ModelParams.named("robot")
    steps, seed, memory = 80, 0, 60
    spec = controller_specs(params, ["optimal"])[0][1]
    fixed = binarizer == "fixed"
    threshold = f"fixed:{FIXED_THRESHOLD['threshold_db']}" if fixed else binarizer
    offline = run_room(params, room, spec, threshold, steps * 0.5, seed, run, memory,
                       default_check_in(params))  # controller_node's
    steps = len(offline.y)  # the default source's warm-up windows give no step
    attentive = offline_postures(offline.belief, ATTENTIVE_ABOVE, BORED_BELOW)  # posture_node's
    expected = ["bored"]  # posture_node's initial posture, then every change
    for now in attentive:
        if ("attentive" if now else "bored") != expected[-1]:
            expected.append("attentive" if now else "bored")
    fake_room = {"room": room, "seed": room_seed(seed, room, run)}
    if not fixed:
        fake_room["max_windows"] = 0  # more windows than steps
    source = {} if fixed else {"bit_source": {}}
    with stepped_graph(room_nodes(fake_room, steps, memory_steps=memory, **source),
                       "fake_audio_node") as graph:  # fmt: skip
        graph.run_steps(steps)
        rec = graph.recorder
        assert rec.sound[:steps] == [bool(y) for y in offline.y]
        assert rec.vocalize[:steps] == [bool(u) for u in offline.u]
        assert rec.belief[:steps] == list(offline.belief)
        graph.run_until(lambda: len(rec.posture) >= len(expected), "every posture change")
        assert postures(graph) == expected
        assert 0 < sum(offline.u) < steps and 0 < sum(offline.y) < steps
        assert "attentive" in expected, "the sample must exercise the posture rule"
