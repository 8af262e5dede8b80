"""Parameter files' keys that no node declares are named at start-up (rcl ignores them).

A misspelled key or node section in a ``--params-file`` used to change nothing without a
word; the node it was meant for (or the process, for a section that matches no node) now
warns once, naming the key and the node.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from infomax_contingency.nodes.parameter_files import (
    SHARED_PARAMETERS,
    parameter_sections,
    params_files,
    section_matches,
    undeclared_command_line_parameters,
    undeclared_parameters,
)
from processes import read_until

ROOT = Path(__file__).resolve().parent.parent


class DeclaredNode:
    """A stand-in for a node: its fully qualified name and declared parameters."""

    def __init__(self, name: str, *declared: str) -> None:
        self.name, self.declared = name, set(declared)

    def get_fully_qualified_name(self) -> str:
        return self.name

    def has_parameter(self, name: str) -> bool:
        return name in self.declared


def test_params_files_are_read_from_the_ros_arguments_only() -> None:
    args = ["prog", "--params-file", "mine.yaml", "--ros-args", "--params-file", "a.yaml",
            "-p", "x:=1", "--", "--params-file", "b.yaml", "--ros-args", "--params-file",
            "c.yaml"]  # fmt: skip
    assert params_files(args) == ["a.yaml", "c.yaml"]


def test_sections_and_their_dotted_parameter_names() -> None:
    document = yaml.safe_load(
        "/**:\n  ros__parameters: {window_s: 0.5}\n"
        "/**/mic_node:\n  ros__parameters: {source: topic, vad: {frame_ms: 30}}\n"
        "ns:\n  belief_node:\n    ros__parameters: {memory_steps: 0}\n"
    )
    assert list(parameter_sections(document)) == [
        ("/**", ["window_s"]),
        ("/**/mic_node", ["source", "vad.frame_ms"]),
        ("/ns/belief_node", ["memory_steps"]),
    ]


@pytest.mark.parametrize(
    ("pattern", "node", "matches"),
    [
        ("/**", "/mic_node", True),
        ("/**", "/robot/left/mic_node", True),
        ("/**/mic_node", "/mic_node", True),
        ("/**/mic_node", "/robot/mic_node", True),
        ("/mic_node", "/robot/mic_node", False),
        ("/*/mic_node", "/robot/mic_node", True),
        ("/*/mic_node", "/mic_node", False),
        ("/robot/**", "/robot/a/b", True),
        ("/robot/**", "/other/mic_node", False),
        ("/**/mic_nod", "/mic_node", False),
    ],
)
def test_a_section_applies_to_a_node_by_rcls_rule(pattern: str, node: str, matches: bool) -> None:
    assert section_matches(pattern, node) is matches


def test_undeclared_keys_and_sections_that_match_no_node_are_named(tmp_path: Path) -> None:
    file = tmp_path / "p.yaml"
    file.write_text(
        "/**:\n  ros__parameters: {window_s: 0.5, windw_s: 0.5, memory_steps: 5}\n"
        "/**/mic_node:\n  ros__parameters: {source: topic, sorce: wav}\n"
        "/**/belief_node:\n  ros__parameters: {memory_steps: 0}\n"  # another process's
        "/**/micnode:\n  ros__parameters: {source: topic}\n"
        "/other/**:\n  ros__parameters: {anything: 1}\n"  # another namespace's
    )
    mic = DeclaredNode("/mic_node", "source", "window_s")
    found = undeclared_parameters([str(tmp_path / "missing.yaml"), str(file)], [mic])
    assert found == [
        (mic, f"parameter file {file}: 'windw_s' (section '/**') is not a parameter of"
              " /mic_node: ignored"),
        # memory_steps is belief_node's: a '/**' key is named when nobody here has it
        (mic, f"parameter file {file}: 'memory_steps' (section '/**') is not a parameter of"
              " /mic_node: ignored"),
        (mic, f"parameter file {file}: 'sorce' (section '/**/mic_node') is not a parameter"
              " of /mic_node: ignored"),
        (None, f"parameter file {file}: section '/**/micnode' matches no node (the package's"
               " nodes: mic_node, controller_node, belief_node, posture_node, fake_audio_node,"
               " speaker_node, recorder_node); its parameters source are ignored"),
    ]  # fmt: skip
    belief = DeclaredNode("/belief_node", "memory_steps")
    assert [m for _, m in undeclared_parameters([str(file)], [mic, belief])
            if "'memory_steps'" in m] == []  # fmt: skip


def test_command_line_parameters_a_node_does_not_take_are_named() -> None:
    """``-p`` values rcl ignores: a typo, another bit source's setting; another node's not."""

    class Mic(DeclaredNode):
        parameters = type("Reader", (), {"known": {"threshold_db"}})()

        def get_name(self) -> str:
            return "mic_node"

    mic = Mic("/robot1/mic_node", "source", "bit_source")
    args = ["mic_node", "--ros-args", "-p", "mic_node:threshold_db:=-35.0", "-p",
            "sorce:=wav", "--param", "posture_node:attentive_above:=0.5", "-p",
            "source:=topic", "-p", "use_sim_time:=true", "--", "-p", "x:=1"]  # fmt: skip
    assert [m for _, m in undeclared_command_line_parameters(args, [mic])] == [
        "-p threshold_db is a setting of another bit source than /robot1/mic_node's"
        " (bit_source): ignored",
        "-p sorce is not a parameter of /robot1/mic_node: ignored",
    ]
    # several nodes in one process (bringup): a -p without a node name is every node's,
    # so one node that takes it is enough; one that none takes is named once
    posture = DeclaredNode("/robot1/posture_node", "attentive_above")
    posture.get_name = lambda: "posture_node"  # type: ignore[attr-defined]
    args = ["x", "--ros-args", "-p", "attentive_above:=0.8", "-p", "atentive_above:=0.8"]
    assert undeclared_command_line_parameters(args, [mic, posture]) == [
        (mic, "-p atentive_above is not a parameter of /robot1/mic_node,"
              " /robot1/posture_node: ignored"),
    ]  # fmt: skip


def test_the_shipped_configs_give_every_node_only_shared_keys_for_all() -> None:
    """Keys a shipped file gives every node are shared ones: no node warns about them."""
    for file in sorted((ROOT / "config").glob("*.yaml")):
        for pattern, keys in parameter_sections(yaml.safe_load(file.read_text())):
            if pattern == "/**":
                assert set(keys) <= SHARED_PARAMETERS, (file, keys)


def test_a_node_names_the_keys_of_its_params_file_it_does_not_take(tmp_path: Path) -> None:
    """The whole path: a node process, the shipped robot.yaml and a file with typos."""
    typos = tmp_path / "typos.yaml"
    typos.write_text(
        "/**/posture_node:\n  ros__parameters: {atentive_above: 0.9}\n"
        "postur_node:\n  ros__parameters: {bored_below: 0.1}\n"
    )
    process = subprocess.Popen(
        [sys.executable, "-m", "infomax_contingency.nodes.entry", "posture_node", "--ros-args",
         "--params-file", str(ROOT / "config" / "robot.yaml"), "--params-file", str(typos)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    text = ""
    try:  # the warnings come before the node spins
        text = read_until(process, "section '/postur_node'", timeout_s=60.0)
    finally:
        process.send_signal(signal.SIGINT)
        text += process.communicate(timeout=30)[0]
    assert text.count("is not a parameter") == 1, text
    assert ("'atentive_above' (section '/**/posture_node') is not a parameter of"
            " /posture_node: ignored") in text  # fmt: skip
    assert "section '/postur_node' matches no node" in text
    assert "bored_below are ignored" in text
    assert process.returncode == 0


@pytest.mark.parametrize("extra", ["fake_room.yaml", "paper.yaml"])
def test_the_shipped_configs_name_nothing_for_any_node(extra: str) -> None:
    """config/robot.yaml sets every bit source's settings: none is a misspelling."""
    import rclpy
    from rclpy.context import Context

    from infomax_contingency.nodes.belief_node import BeliefNode
    from infomax_contingency.nodes.controller_node import ControllerNode
    from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
    from infomax_contingency.nodes.mic_node import MicNode
    from infomax_contingency.nodes.posture_node import PostureNode
    from infomax_contingency.nodes.speaker_node import SpeakerNode

    files = [str(ROOT / "config" / "robot.yaml"), str(ROOT / "config" / extra)]
    context = Context()
    arguments = ["--params-file", files[0], "--params-file", files[1], "-p", "dry_run:=true"]
    rclpy.init(context=context, args=["test", "--ros-args", *arguments])
    nodes = []
    try:
        for node_class in (MicNode, ControllerNode, BeliefNode, PostureNode, FakeAudioNode,
                           SpeakerNode):  # fmt: skip
            nodes.append(node_class(context=context))
            assert undeclared_parameters(files, nodes[-1:]) == [], node_class.NODE_NAME
        assert undeclared_parameters(files, nodes) == []
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
