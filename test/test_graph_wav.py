"""Replaying a recorded interaction (test/data/interaction.wav) through the node graph.

mic_node (source wav, lockstep, k-means calibration on the first 10 s), controller_node
and belief_node in the test process on one hand-stepped executor (real DDS between
them); the recorder plays the part of ``ros2 topic echo``. The published bits must equal
the core's offline computation on the same file, and the belief stream an offline run of
the same statistic on those bits and the published decisions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.resample import load_mono
from infomax_contingency.audio.threshold import calibration_window_count, kmeans_threshold
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.core.model import ModelParams, StatisticTracker
from stepped_graph import stepped_graph

WAV = Path(__file__).parent / "data" / "interaction.wav"
WINDOW_S, CALIBRATION_S = 0.5, 10.0


def test_recorded_interaction_replays_like_the_offline_computation() -> None:
    energies = window_energies_db(load_mono(WAV), 16000, WINDOW_S)
    threshold = kmeans_threshold(energies[: calibration_window_count(CALIBRATION_S, WINDOW_S)])
    expected_bits = [bool(e > threshold) for e in energies]
    steps = len(energies)
    assert 20 <= steps and 0 < sum(expected_bits) < steps

    mic = {
        "source": "wav",
        "wav_file": str(WAV),
        "lockstep": True,
        "exit_at_end": True,
        "window_s": WINDOW_S,
        "bit_source": "energy",
        "threshold_mode": "calibrate",
        "calibration_s": CALIBRATION_S,
        "wait_for_listeners": 3,
    }
    nodes = {"controller_node": {"wait_for_listeners": 3}, "belief_node": {"memory_steps": 0},
             "mic_node": mic}  # fmt: skip
    with stepped_graph(nodes, "mic_node") as graph:
        graph.run_steps(steps)
        mic_node = graph.nodes["mic_node"]
        graph.run_until(mic_node.finished.done, "mic_node to finish at the end of the file")
        assert mic_node.finished.result() == 0
        graph.executor.run_for_callbacks(20)
        rec = graph.recorder
        assert len(rec.sound) == steps, "one bit per window of the file, no more"
        assert rec.sound == expected_bits
        assert np.array_equal(np.float32(rec.energy), energies.astype(np.float32))

        params = ModelParams.named("robot")
        tracker = StatisticTracker(params)
        offline = []
        for y, u in zip(rec.sound, rec.vocalize, strict=True):
            offline.append(tracker.observe(y).belief(params))
            tracker.act(u)
        assert rec.belief == offline
        assert any(rec.vocalize), "the controller must have vocalized at least once"


@pytest.mark.parametrize(
    ("bit_source", "options"),
    [
        ("speech_band", {"threshold_mode": "calibrate", "calibration_s": CALIBRATION_S}),
        ("energy", {"threshold_mode": "noise_floor", "calibration_s": 2.0}),
        ("vad", {}),
    ],
)
def test_recorded_interaction_replays_like_the_offline_bit_source(
    bit_source: str, options: dict[str, Any]
) -> None:
    windows = WavReplay(WAV, WINDOW_S, samples=True)
    offline = make_bit_source(bit_source, 16000, WINDOW_S, **options)
    if options.get("threshold_mode") == "calibrate":  # a file is calibrated by reading ahead
        offline.calibrate_ahead(*windows.read_ahead(CALIBRATION_S, WINDOW_S))
    bits = [offline.push_window(windows.next_window()) for _ in range(windows.n_windows)]
    expected = [bit for bit in bits if bit is not None]
    assert 0 < sum(expected) < len(expected)

    mic = {
        "source": "wav",
        "wav_file": str(WAV),
        "lockstep": True,
        "exit_at_end": True,
        "window_s": WINDOW_S,
        "bit_source": bit_source,
        "wait_for_listeners": 3,
        **options,
    }
    nodes = {"controller_node": {}, "belief_node": {"memory_steps": 0}, "mic_node": mic}
    with stepped_graph(nodes, "mic_node") as graph:
        graph.run_steps(len(expected))
        mic_node = graph.nodes["mic_node"]
        graph.run_until(mic_node.finished.done, "mic_node to finish at the end of the file")
        assert mic_node.finished.result() == 0
        graph.executor.run_for_callbacks(20)
        assert graph.recorder.sound == expected


def test_self_calibrating_threshold_in_the_graph_equals_the_offline_loop(tmp_path: Path) -> None:
    """bit_source background: the decisions label the windows; graph == offline loop."""
    from infomax_contingency.audio.wav import write_wav_int16
    from infomax_contingency.core.controllers import PolicyController, default_check_in
    from infomax_contingency.core.policy_table import PolicyTable
    from infomax_contingency.eval.rooms import render_room
    from infomax_contingency.eval.sessions import wav_background_loop
    from infomax_contingency.resources import resource_path

    # an office without the robot's sound: distant talkers, knocks and a door
    samples, _, rate = render_room("office", 20.0, seed=5, controller="fixed:100000")
    wav = tmp_path / "office.wav"
    write_wav_int16(wav, samples, rate)
    params = ModelParams.named("robot")
    table = PolicyTable.load(
        resource_path("policies", "robot_receding_H24_M60.npz"), expected_params=params
    )
    offline = list(wav_background_loop(wav, params, None,
                                       PolicyController(table, params, default_check_in(params))))
    steps = len(offline)
    assert 20 <= steps < 40, "the first windows only hear the room"
    assert any(r.u for r in offline) and 0 < sum(r.y for r in offline) < steps

    mic = {"source": "wav", "wav_file": str(wav), "lockstep": True, "exit_at_end": True,
           "window_s": WINDOW_S, "bit_source": "background", "wait_for_listeners": 3}
    nodes = {"controller_node": {"wait_for_listeners": 3}, "belief_node": {"memory_steps": 0},
             "mic_node": mic}  # fmt: skip
    with stepped_graph(nodes, "mic_node") as graph:
        graph.run_steps(steps)
        mic_node = graph.nodes["mic_node"]
        graph.run_until(mic_node.finished.done, "mic_node to finish at the end of the file")
        graph.executor.run_for_callbacks(20)
        rec = graph.recorder
        assert rec.sound == [bool(r.y) for r in offline]
        assert rec.vocalize == [bool(r.u) for r in offline]
        assert rec.belief == [r.belief for r in offline]
        assert mic_node.bits.rule.labelled["self"] > 0, "the decisions reached the mic"
