"""The docs stay true: the parameter reference, the README's ROS API, every name they use.

- docs/PARAMETERS.md equals what the nodes declare (regenerated here, diffed);
- each README "ROS API" table equals what the running nodes subscribe to, publish and
  serve, and names only parameters they declare (the whole graph in this process, on a
  hand-stepped executor, a few steps against the fake room);
- README.md and docs/*.md name no file, command, option, parameter or topic that does
  not exist (``doc_references``).
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

import doc_references as refs
from doc_references import ROOT, Repository
from graph_harness import room_nodes
from infomax_contingency.cli.main import build_parser
from infomax_contingency.nodes import parameter_reference
from infomax_contingency.nodes.entry import NODES
from stepped_graph import stepped_graph

DOCS = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
        *sorted((ROOT / "docs" / "history").glob("*.md")), ROOT / "policies" / "README.md")

KNOWN_STALE: dict[str, set[str]] = {}
"""Stale names, by doc (e.g. ``{"docs/RESULTS.md": {"file `x.py`"}}``), that another
change is rewriting: the list can only shrink — an entry that is fixed fails the test
until it is removed here. Empty today."""

README_MAX_LINES, README_MAX_BYTES = 200, 10 * 1024
"""The README fits on a screen or two; detail goes to docs/."""

RESULTS_MAX_LINES = 400
"""docs/RESULTS.md gives each experiment its question, command, table, figure and
conclusion; sweeps that are not results of the current defaults go to docs/history/."""

RCLPY_PUBLISHERS = frozenset({"/rosout", "/parameter_events"})
"""What rclpy publishes for every node by itself."""

RCLPY_SERVICES = frozenset({
    "describe_parameters", "get_parameter_types", "get_parameters", "list_parameters",
    "set_parameters", "set_parameters_atomically", "get_type_description",
})
"""The services rclpy gives every node (``~/<name>``) by itself."""


def _relative(name: str) -> str:
    """``~/reset`` -> ``reset``; ``/diagnostics`` -> ``diagnostics``."""
    return name.removeprefix("~/").lstrip("/")


@pytest.fixture(scope="module")
def readme_api() -> dict[str, refs.NodeApi]:
    return refs.ros_api_tables((ROOT / "README.md").read_text(), NODES)


@pytest.fixture(scope="module")
def repository(readme_api: dict[str, refs.NodeApi]) -> Repository:
    reference = (ROOT / "docs" / "PARAMETERS.md").read_text()
    declared = refs.parameter_reference(reference)
    topics = {_relative(topic) for api in readme_api.values()
              for topic in api.subscribes + api.publishes}
    services = {node: {_relative(s) for s in api.services} for node, api in readme_api.items()}
    names = {path.name for path in ROOT.rglob("*")
             if not {".git", ".venv", "build", "install", "log"} & set(path.parts)}
    return Repository(
        parameters=declared, topics=topics, services=services,
        executables=refs.console_scripts(), make_targets=refs.make_targets(),
        cli=build_parser(), launch_arguments=refs.launch_arguments(), tracked_names=names,
        live=refs.live_parameters(reference),
        choices=refs.choice_values(reference),
    )


def test_the_parameter_reference_is_what_the_nodes_declare() -> None:
    committed = (ROOT / "docs" / "PARAMETERS.md").read_text()
    generated = parameter_reference.generate()
    diff = "".join(difflib.unified_diff(
        committed.splitlines(keepends=True), generated.splitlines(keepends=True),
        "docs/PARAMETERS.md (committed)", "docs/PARAMETERS.md (the nodes now)", n=0))
    assert not diff, (
        f"docs/PARAMETERS.md is stale; regenerate it with `make params-doc`"
        f" ({parameter_reference.COMMAND}):\n{diff[:3000]}")


def test_the_parameter_reference_is_written_whole_or_refused_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(parameter_reference, "generate", lambda: "# reference\n")
    out = tmp_path / "PARAMETERS.md"
    assert parameter_reference.main(["--out", str(out)]) == 0
    assert out.read_text() == "# reference\n" and [p.name for p in tmp_path.iterdir()] == [
        "PARAMETERS.md"]  # no temporary file left beside it

    def never() -> str:
        raise AssertionError("the nodes were started for a path that cannot be written")

    monkeypatch.setattr(parameter_reference, "generate", never)
    assert parameter_reference.main(["--out", str(tmp_path)]) == 2  # a directory
    err = capsys.readouterr().err
    assert err.startswith("parameter_reference: ") and err.count("\n") == 1, err


SPECIAL_VALUE = re.compile(r"(?:^|[;(,] )(negative|-?\d+(?:\.\d+)?) = ")
"""A description's special value ("-1 = no partner", "negative = never", "0 = the whole")."""


def test_the_special_values_a_description_names_are_in_its_range() -> None:
    """partner_arrive_s said "negative = no partner", but its range stops at -1.

    ``ros2 param set /fake_audio_node partner_arrive_s -5`` was refused. Every value a
    description names, and "negative" (any negative number), must lie in the range.
    """
    wrong = []
    for line in (ROOT / "docs" / "PARAMETERS.md").read_text().splitlines():
        cells = [cell.strip() for cell in line.strip("|").split(" | ")]
        bounds = re.fullmatch(r"a number in \[(\S+), (\S+)\].*", cells[3]) if len(cells) == 6 \
            else None  # fmt: skip
        if bounds is None:
            continue
        low, high = float(bounds[1]), float(bounds[2])
        for value in SPECIAL_VALUE.findall(cells[5]):
            if not (low <= -1e9 if value == "negative" else low <= float(value) <= high):
                wrong.append(f"{cells[0]}: {value!r} = ... outside [{low:g}, {high:g}]")
    assert not wrong, wrong


def test_the_readme_fits_on_a_screen() -> None:
    text = (ROOT / "README.md").read_bytes()
    lines = text.count(b"\n")
    assert lines <= README_MAX_LINES and len(text) <= README_MAX_BYTES, (
        f"README.md has {lines} lines and {len(text)} bytes (at most {README_MAX_LINES} and"
        f" {README_MAX_BYTES}): move detail to docs/ (map in the README)")


def test_the_results_stay_in_proportion() -> None:
    lines = (ROOT / "docs" / "RESULTS.md").read_bytes().count(b"\n")
    assert lines <= RESULTS_MAX_LINES, (
        f"docs/RESULTS.md has {lines} lines (at most {RESULTS_MAX_LINES}): one table per question;"
        " move sweeps that are not results of the current defaults to docs/history/")


def test_the_readme_maps_every_doc() -> None:
    readme = (ROOT / "README.md").read_text()
    unmapped = [path.name for path in sorted((ROOT / "docs").glob("*.md"))
                if f"](docs/{path.name})" not in readme]
    assert not unmapped, f"README.md's map of docs/ lacks {unmapped}"


def test_the_readme_lists_every_command() -> None:
    readme = (ROOT / "README.md").read_text()
    commands = refs.subparsers(build_parser())
    missing = [name for name in commands if f"| `{name}` |" not in readme]
    assert not missing, f"README.md's command table lacks {missing}"


def test_every_node_has_a_ros_api_table(readme_api: dict[str, refs.NodeApi]) -> None:
    missing = [node for node in NODES if node not in readme_api]
    assert not missing, f"README.md has no '### `node`' ROS API table for {missing}"


@pytest.fixture(scope="module")
def running_graph(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """Every node of the package, running together against the fake room (a few steps).

    Every optional topic on: the room's robot speaks and declares it, posture_node
    declares its moves (both on ``self_sound``).
    """
    steps = 6
    nodes = room_nodes({"room": "responsive", "seed": 1}, steps)
    nodes["controller_node"]["wait_for_listeners"] += 1  # the recorder hears decisions too
    # what some nodes publish only when asked to: the robot's own sound on self_sound
    nodes["posture_node"]["declare_motion_sound"] = True
    nodes["fake_audio_node"]["robot_speech_probability"] = 0.5
    nodes["speaker_node"] = {}
    nodes["recorder_node"] = {"directory": str(tmp_path_factory.mktemp("bag") / "session")}
    with stepped_graph(nodes, "fake_audio_node") as graph:
        graph.run_steps(steps)
        recorder = graph.nodes["recorder_node"]
        graph.run_until(lambda: {"audio", "partner_present"} <= recorder.subscribed,
                        "the recorder's subscriptions to the topics it waits for")
        yield graph.nodes


def _running_api(node) -> refs.NodeApi:  # noqa: ANN001 - an rclpy Node
    own = f"{node.get_fully_qualified_name()}/"
    return refs.NodeApi(
        subscribes=sorted({s.topic_name for s in node.subscriptions}),
        publishes=sorted({p.topic_name for p in node.publishers} - RCLPY_PUBLISHERS),
        services=sorted({node.resolve_service_name(s.srv_name) for s in node.services}
                        - {own + name for name in RCLPY_SERVICES}),
    )


# One worker runs every node's case: each worker that ran one started the module's whole
# graph again (with `--dist loadgroup`).
@pytest.mark.xdist_group("readme_api_graph")
@pytest.mark.parametrize("executable", NODES)
def test_the_readme_ros_api_table_is_what_the_node_does(
    executable: str, readme_api: dict[str, refs.NodeApi], running_graph: dict
) -> None:
    if executable not in readme_api:
        pytest.fail(f"README.md has no ROS API table for {executable}")
    node = running_graph[executable]
    documented, running = readme_api[executable], _running_api(node)
    for row in ("subscribes", "publishes"):
        listed = sorted({node.resolve_topic_name(name) for name in getattr(documented, row)})
        assert listed == getattr(running, row), (
            f"README.md, {executable} {row}: lists {listed}, the node {row}"
            f" {getattr(running, row)}")
    listed = sorted({node.resolve_service_name(name) for name in documented.services})
    assert listed == running.services, (
        f"README.md, {executable} services: lists {listed}, the node serves {running.services}")
    undeclared = [name for name in documented.parameters if not node.has_parameter(name)]
    assert not undeclared, f"README.md, {executable} key parameters: not declared: {undeclared}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda path: str(path.relative_to(ROOT)))
def test_a_doc_names_only_what_exists(doc: Path, repository: Repository) -> None:
    text = doc.read_text()
    every_problem = (refs.missing_files(doc, text, repository)
                     + refs.missing_commands(text, repository)
                     + refs.missing_parameters_and_topics(text, repository))
    known = KNOWN_STALE.get(str(doc.relative_to(ROOT)), set())
    problems = [problem for problem in every_problem if problem not in known]
    assert not problems, f"{doc.relative_to(ROOT)} names what does not exist: " + ", ".join(
        dict.fromkeys(problems))
    fixed = known - set(every_problem)
    assert not fixed, f"{sorted(fixed)} fixed in {doc.relative_to(ROOT)}: remove from KNOWN_STALE"


def test_the_checks_find_what_does_not_exist(repository: Repository) -> None:
    """Each rule catches a name that is not there (and passes its existing twin)."""
    doc = ROOT / "docs" / "EXAMPLE.md"
    text = "\n".join([
        "`config/robot.yaml` `config/robots.yaml` `core/model.py` `core/models.py`",
        "`infomax_contingency.core.model.Statistic` `core.model.Statistics`",
        "[model](MODEL.md) [gone](GONE.md)",
        "```", "infomax-contingency simulate --steps 3 --stepz 3",
        "infomax-contingency simulat", "infomax-contingency experiment baby10",
        "ros2 run infomax_contingency mic_node --ros-args -p threshold_db:=-30 -p threshold:=1",
        "ros2 run infomax_contingency mic_nod",
        "ros2 launch infomax_contingency contingency.launch.py namespace:=r1 fake_rooms:=true",
        "ros2 param set /robot1/posture_node bored_below 0.3",
        "ros2 param set /posture_node bored_under 0.3",
        "ros2 param set /mic_node source wav  # refused: read-only",
        "ros2 param set /mic_node threshold_mode fixed",
        "ros2 topic echo /robot1/belief", "ros2 topic echo --once /beliefs",
        "ros2 service call /belief_node/reset std_srvs/srv/Trigger",
        "ros2 service call /belief_node/restart std_srvs/srv/Trigger",
        "make demo", "make demos", "bringup -p mic_node:source:=wav -p mic_node:sauce:=wav",
        "```",
        "`belief_node.memory_steps` `belief_node.memory` `mic_node.MicNode`",
        "mic_node's `calibrate`, mic_node's `calibration`",
        "| `threshold_mode` | x |", "|---|---|", "",
        "| `thresh_mode` | x |", "|---|---|", "",
        "| topic | type |", "|---|---|", "| `sound_step` | x |", "| `sound_steps` | x |",
        "`realtime:=false` `real_time:=false` `test_model` `test_modle`",
        "", "| command | what |", "|---|---|", "| `room-wav` | x |", "| `room-wave` | x |",
    ])
    problems = (refs.missing_files(doc, text, repository)
                + refs.missing_commands(text, repository)
                + refs.missing_parameters_and_topics(text, repository))
    assert sorted(problems) == sorted([
        "file `config/robots.yaml`", "file `core/models.py`", "name `core.model.Statistics`",
        "link `GONE.md`",
        "option `infomax-contingency simulate --stepz`",
        "command `infomax-contingency simulat`",
        "command `infomax-contingency experiment baby10`",
        "parameter `mic_node:threshold`", "executable `ros2 run infomax_contingency mic_nod`",
        "launch argument `contingency.launch.py fake_rooms:=`",
        "parameter `posture_node:bored_under`", "topic `/beliefs`",
        "service `/belief_node/restart`", "make target `demos`", "parameter `mic_node:sauce`",
        "parameter `belief_node.memory`", "parameter `thresh_mode` (table header)",
        "topic `sound_steps` (table)", "launch argument `real_time:=`",
        "test `test_modle`", "command `room-wave` (table)", "parameter `calibration` of mic_node",
        "live parameter `mic_node:threshold_mode`",
    ]), problems
