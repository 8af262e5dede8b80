"""mic_node ``source: bag``: a recorded session replayed into the node graph.

mic_node serves the committed session's recorded bits (the bag holds no audio),
controller_node answers each step with the robot's recorded decision (``controller:
recorded:BAG``) and belief_node computes the belief: it equals the recorded belief step
for step. With the robot's table instead, the graph decides again on the same bits.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from infomax_contingency.audio.bag_replay import BagReplay, recorded_decisions
from infomax_contingency.eval.sessions import load_session
from stepped_graph import stepped_graph

SESSION = Path(__file__).parent / "data" / "session_demo"

pytestmark = pytest.mark.xdist_group("node_graphs")


def _graph(controller: dict) -> dict:
    mic = {"source": "bag", "bag_dir": str(SESSION), "lockstep": True, "exit_at_end": True,
           "threshold_mode": "fixed", "wait_for_listeners": 3}
    return {"controller_node": controller, "belief_node": {"memory_steps": 60}, "mic_node": mic}


def _replay(controller: dict) -> tuple[list, list, list]:
    with stepped_graph(_graph(controller), "mic_node") as graph:
        graph.run_steps(120)
        mic_node = graph.nodes["mic_node"]
        graph.run_until(mic_node.finished.done, "mic_node to finish at the end of the bag")
        assert mic_node.finished.result() == 0
        graph.executor.run_for_callbacks(20)
        rec = graph.recorder
        return list(rec.sound), list(rec.vocalize), list(rec.belief)


def test_a_session_with_its_recorded_decisions_replays_to_the_recorded_belief() -> None:
    session = load_session(SESSION)
    bits, decisions, beliefs = _replay({"controller": f"recorded:{SESSION}"})
    assert bits == [bit for _, bit in session.bits]
    assert decisions == [u for _, u in session.decisions]
    assert beliefs == session.beliefs


def test_the_bag_reader_serves_the_recorded_bits_and_decisions() -> None:
    replay = BagReplay(SESSION, 0.5, 16000)
    session = load_session(SESSION)
    assert not replay.has_audio and replay.n_windows == 120
    served = [replay.next_window() for _ in range(120)]
    assert [bit for _, bit in served] == [bit for _, bit in session.bits]
    assert replay.next_window() is None
    assert recorded_decisions(SESSION) == [u for _, u in session.decisions]
