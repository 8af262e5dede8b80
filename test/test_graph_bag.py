"""mic_node ``source: bag``: a recorded session replayed into the node graph.

mic_node serves the committed session's recorded bits (the bag holds no audio),
controller_node answers each step with the robot's recorded decision (``controller:
recorded:BAG``) and belief_node computes the belief: it equals the recorded belief step
for step. With the robot's table instead, the graph decides again on the same bits.
A bag with audio goes through mic_node's bit source (``bit_source``); recorded bits
bypass it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from infomax_contingency.audio.bag import BagWriter, encode, read_topics
from infomax_contingency.audio.bag_replay import BagReplay, recorded_decisions
from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.eval.sessions import load_session
from stepped_graph import stepped_graph

SESSION = Path(__file__).parent / "data" / "session_demo"
ONE_K2 = Path(__file__).parent / "data" / "robot_one_k2.yaml"
STEP_TOPICS = ("/sound", "/sound_step", "/vocalize", "/vocalize_step", "/belief",
               "/partner_present")


def _graph(controller: dict, bag: Path = SESSION, **mic_parameters: object) -> dict:
    mic = {"source": "bag", "bag_dir": str(bag), "lockstep": True, "exit_at_end": True,
           "bit_source": "energy", "threshold_mode": "fixed", "wait_for_listeners": 3,
           **mic_parameters}
    # the committed session was recorded with one K2 (its belief_node did not say so yet)
    belief = {"memory_steps": 60, "params": str(ONE_K2) if bag == SESSION else "robot"}
    return {"controller_node": controller, "belief_node": belief, "mic_node": mic}


def _replay(controller: dict, bag: Path = SESSION, steps: int = 120,
            **mic_parameters: object) -> tuple[list, list, list]:
    with stepped_graph(_graph(controller, bag, **mic_parameters), "mic_node") as graph:
        graph.run_steps(steps)
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


def test_a_recorded_room_session_holds_every_step_of_every_topic(tmp_path: Path) -> None:
    """The recorder subscribes before the graph starts: no topic misses a step.

    The graph (fake room, mic, controller, belief, recorder) waits for the recorder as a
    listener of ``sound_step``, ``partner_present`` and ``audio``, as the demo does when
    it records; the stepped graph also waits for its ``session_info``.
    """
    bag = tmp_path / "session"
    steps = 40
    nodes = {
        "controller_node": {}, "belief_node": {"memory_steps": 60},
        "recorder_node": {"directory": str(bag)},
        "mic_node": {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed",
                     "wait_for_listeners": 3},
        "fake_audio_node": {"seed": 3, "max_windows": steps, "wait_for_truth_listeners": 2,
                            "wait_for_listeners": 2},  # audio: the mic and the recorder
    }
    with stepped_graph(nodes, "fake_audio_node") as graph:
        graph.run_steps(steps)
        recorder = graph.nodes["recorder_node"]
        graph.run_until(lambda: all(recorder.counts.get(topic, 0) >= steps for topic in
                                    (*STEP_TOPICS, "/audio")), "the recorder to record all")
        truth = list(graph.recorder.partner_present)
    topics = read_topics(bag, (*STEP_TOPICS, "/audio", "/session_info"))
    for topic in (*STEP_TOPICS, "/audio"):
        assert len(topics[topic]) == steps, (topic, len(topics[topic]))
    assert [int(m.data[1]) for _, m in topics["/sound_step"]] == list(range(1, steps + 1))
    assert [m.data for _, m in topics["/partner_present"]] == truth
    assert len(topics["/session_info"]) == 1


# ------------------------------------------------------------------ bit sources

RATE_HZ = 16000
WINDOW = RATE_HZ // 2  # 0.5 s


def _audio_bag(directory: Path) -> np.ndarray:
    """A bag holding only audio: loud 100 Hz hum and quieter 1 kHz tone, by turns.

    The hum is louder in full-band energy, the tone in the 300-3400 Hz band, so the
    bits of ``energy`` and ``speech_band`` at -30 dB differ. Returns the windows (rows).
    """
    t = np.arange(WINDOW) / RATE_HZ
    hum = 0.5 * np.sin(2 * np.pi * 100.0 * t)  # about -9 dB, almost nothing in the band
    tone = 0.05 * np.sin(2 * np.pi * 1000.0 * t)  # about -29 dB, all in the band
    quiet = np.zeros(WINDOW)
    windows = np.array([hum, tone, quiet, tone, hum, hum, tone, quiet])
    writer = BagWriter(directory)
    writer.add_topic("/audio", "std_msgs/msg/Float32MultiArray", [{}])
    for index, chunk in enumerate(windows.reshape(-1, WINDOW // 4)):  # chunks of 1/4 window
        writer.write("/audio", encode("std_msgs/msg/Float32MultiArray", data=chunk),
                     (index + 1) * 125_000_000)
    writer.close()
    return windows


def test_the_bag_reader_keeps_the_samples_of_a_bag_with_audio(tmp_path: Path) -> None:
    windows = _audio_bag(tmp_path / "audio")
    plain = BagReplay(tmp_path / "audio", 0.5, RATE_HZ)
    kept = BagReplay(tmp_path / "audio", 0.5, RATE_HZ, samples=True)
    assert plain.window_samples is None and kept.n_windows == plain.n_windows == len(windows)
    assert kept.last_samples is None
    for row in windows:
        assert kept.next_window() == plain.next_window()
        np.testing.assert_array_equal(kept.last_samples, row.astype(np.float32))
    np.testing.assert_array_equal(kept.calibration_windows(1.0, 0.5),
                                  windows[:2].astype(np.float32))  # fmt: skip
    assert BagReplay(SESSION, 0.5, RATE_HZ, samples=True).window_samples is None  # no audio


def test_a_bag_with_audio_goes_through_the_bit_source(tmp_path: Path) -> None:
    windows = _audio_bag(tmp_path / "audio").astype(np.float32).astype(np.float64)
    offline = make_bit_source("speech_band", RATE_HZ, 0.5, threshold_mode="fixed",
                              threshold_db=-35.0)  # fmt: skip
    expected = [offline.push_window(row) for row in windows]
    energy_bits = [bool(e > -35.0) for e, _ in BagReplay(tmp_path / "audio", 0.5, RATE_HZ).windows]
    assert expected != energy_bits, "the test bag must tell the two sources apart"
    bits, _, _ = _replay({}, tmp_path / "audio", len(windows), bit_source="speech_band",
                         threshold_db=-35.0)  # fmt: skip
    assert bits == expected


def test_a_bag_without_audio_replays_its_recorded_bits_whatever_the_bit_source() -> None:
    session = load_session(SESSION)
    bits, _, _ = _replay({"controller": f"recorded:{SESSION}"}, bit_source="vad")
    assert bits == [bit for _, bit in session.bits]
