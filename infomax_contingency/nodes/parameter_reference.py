"""docs/PARAMETERS.md, generated from the parameters the nodes declare.

Every node executable (:data:`~infomax_contingency.nodes.entry.NODES`) is constructed in
this process with its defaults, and each parameter it declares is read back from rclpy
as declared: its default, type, description, the values allowed (the descriptor's
``additional_constraints`` or range), and whether it is read-only. Nothing is written by
hand, so the reference cannot drift from the code; ``test/test_docs.py`` regenerates it
and fails, naming the command, when the committed file differs::

    python -m infomax_contingency.nodes.parameter_reference --out docs/PARAMETERS.md
    make params-doc                                             # the same

A node that needs a value to start at all (the recorder's bag ``directory``) gets one
from :data:`VALUES_TO_START`; the reference shows the declared default, not that value.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from infomax_contingency.limits import check_output_file, written_atomically
from infomax_contingency.nodes.entry import NODES

VALUES_TO_START: dict[str, dict[str, Any]] = {"recorder_node": {"directory": "{tmp}/bag"}}
"""Node -> parameter values it cannot start without (``{tmp}``: a temporary directory)."""

RCLPY_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
"""Parameters rclpy declares on every node by itself (not this package's)."""

COMMAND = "python -m infomax_contingency.nodes.parameter_reference --out docs/PARAMETERS.md"
"""The command that regenerates the committed reference (also ``make params-doc``)."""


@dataclass(frozen=True)
class DeclaredParameter:
    """One parameter as a node declared it."""

    name: str
    default: Any
    type_name: str
    description: str
    allowed: str
    live: bool

    def row(self) -> str:
        """A Markdown table row: name, type, default, allowed, live, description."""
        cells = (f"`{self.name}`", self.type_name, f"`{_format_value(self.default)}`",
                 self.allowed, "live" if self.live else "", self.description)
        return "| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |"


def _format_value(value: Any) -> str:
    if isinstance(value, str):
        return f'"{value}"' if value == "" or value != value.strip() else value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_format_value(item) for item in value) + "]"
    if isinstance(value, float):
        return f"{value:g}" if "e" in f"{value:g}" or "." in f"{value:g}" else f"{value:g}.0"
    return str(value)


def _type_name(value: Any, dynamic: bool) -> str:
    if dynamic:
        return "any"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "double"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list | tuple) and value:
        return f"{_type_name(value[0], False)}[]"
    return type(value).__name__


def _allowed(descriptor: Any) -> str:
    if descriptor.additional_constraints:
        return descriptor.additional_constraints
    for ranges in (descriptor.floating_point_range, descriptor.integer_range):
        if ranges:
            return f"[{ranges[0].from_value:g}, {ranges[0].to_value:g}]"
    return ""


@contextmanager
def _first_declarations() -> Iterator[dict[str, tuple[Any, Any]]]:
    """Record each parameter's first declaration (name -> (default, descriptor)).

    The first declaration holds the code's default; a node that checks an override may
    declare the same name again with the value given.
    """
    from rclpy.node import Node

    declared: dict[str, tuple[Any, Any]] = {}
    original = Node.declare_parameters

    def recording(self: Node, namespace: str, parameters: list, *args: Any, **kwargs: Any) -> Any:
        for name, *rest in parameters:
            value = rest[0] if rest else None
            descriptor = rest[1] if len(rest) > 1 else None
            declared.setdefault(f"{namespace}.{name}" if namespace else name, (value, descriptor))
        return original(self, namespace, parameters, *args, **kwargs)

    Node.declare_parameters = recording  # type: ignore[method-assign]
    try:
        yield declared
    finally:
        Node.declare_parameters = original  # type: ignore[method-assign]


def node_class(executable: str) -> type:
    """The node class of the executable ``executable`` (its module's one rclpy Node)."""
    from rclpy.node import Node

    module = importlib.import_module(f"infomax_contingency.nodes.{executable}")
    classes = [cls for _, cls in inspect.getmembers(module, inspect.isclass)
               if issubclass(cls, Node) and cls.__module__ == module.__name__]
    if len(classes) != 1:
        raise LookupError(f"{module.__name__} defines {len(classes)} node classes, not one")
    return classes[0]


def _declared_by(executable: str, values: dict[str, Any]) -> list[DeclaredParameter]:
    """What the node of ``executable`` declares when started with ``values``."""
    from rclpy.lifecycle import LifecycleNode
    from rclpy.parameter import Parameter

    with _first_declarations() as declared:
        node = node_class(executable)(
            parameter_overrides=[Parameter(name, value=value) for name, value in values.items()])
        if isinstance(node, LifecycleNode):  # a managed node may declare at configure
            node.trigger_configure()
    try:
        found = []
        for name, (default, _first) in declared.items():
            if name in RCLPY_PARAMETERS:
                continue
            descriptor = node.describe_parameter(name)
            found.append(DeclaredParameter(
                name=name,
                default=list(default) if isinstance(default, list | tuple) else default,
                type_name=_type_name(default, descriptor.dynamic_typing),
                description=descriptor.description,
                allowed=_allowed(descriptor),
                live=not descriptor.read_only,
            ))
        return found
    finally:
        node.destroy_node()


def declared_parameters(executable: str, tmp: str) -> list[DeclaredParameter]:
    """The parameters the node of ``executable`` declares, in declaration order.

    rclpy must be initialised. The node is constructed with its defaults (and
    :data:`VALUES_TO_START`), configured if it is a managed (lifecycle) node, and
    destroyed; once more for each value of a :data:`VARIANTS` choice. A parameter that
    only some values declare says which at the start of its description (unless the
    description already does).
    """
    start = {name: value.format(tmp=tmp) if isinstance(value, str) else value
             for name, value in VALUES_TO_START.get(executable, {}).items()}
    merged: dict[str, DeclaredParameter] = {
        p.name: p for p in _declared_by(executable, start)}
    for choice, values in VARIANTS.get(executable, {}).items():
        by_value = {value: _declared_by(executable, {**start, choice: value})
                    for value in values()}
        for parameters in by_value.values():
            for parameter in parameters:
                merged.setdefault(parameter.name, parameter)
        for name, parameter in list(merged.items()):
            declaring = [value for value, ps in by_value.items() if name in {p.name for p in ps}]
            said = all(f"{choice} {value}" in parameter.description for value in declaring)
            if len(declaring) < len(by_value) and not said:
                merged[name] = dataclasses.replace(parameter, description=(
                    f"({choice} {', '.join(declaring)}) {parameter.description}"))
    return list(merged.values())


def _bit_sources() -> list[str]:
    from infomax_contingency.audio.bitsources import BIT_SOURCES

    return list(BIT_SOURCES)


VARIANTS: dict[str, dict[str, Callable[[], list[Any]]]] = {
    "mic_node": {"bit_source": _bit_sources},
}
"""Node -> a choice parameter whose value decides which other parameters the node
declares -> its values (the reference lists the parameters of every value)."""


HEADER = """\
# Parameters of the nodes

Generated from the nodes' own declarations: do not edit; regenerate with
`{command}` (or `make params-doc`). `test/test_docs.py` fails when this file is stale.

Set them in a parameter file (`config/robot.yaml` for the robot, `config/fake_room.yaml`
for the simulated room) or with `-p NODE:NAME:=VALUE`; `ros2 param describe NODE NAME`
shows the same description and range. *live*: `ros2 param set` changes it while the node
runs (checked as at start-up); every other parameter is read-only and needs a restart.
A bad value stops the node at start-up with one line naming the parameter and what is
allowed.
"""

TABLE_HEAD = (
    "| parameter | type | default | allowed | live | description |\n"
    "|---|---|---|---|---|---|"
)


def reference(nodes: dict[str, list[DeclaredParameter]]) -> str:
    """The Markdown text of docs/PARAMETERS.md for ``nodes`` (executable -> parameters).

    A parameter that every node declares alike is listed once, under "Every node".
    """
    first, *others = nodes.values()
    common = [p for p in first if all(p in parameters for parameters in others)]
    parts = [HEADER.format(command=COMMAND)]
    parts.append("## Every node\n\n" + TABLE_HEAD + "\n"
                 + "\n".join(p.row() for p in common) + "\n")
    for executable, parameters in nodes.items():
        own = [p for p in parameters if p not in common]
        parts.append(f"## {executable}\n\n" + (
            TABLE_HEAD + "\n" + "\n".join(p.row() for p in own) if own
            else "Only the parameters of every node.") + "\n")
    return "\n".join(parts)


def generate() -> str:
    """Construct every node, read what it declares, return the reference text."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    import rclpy

    rclpy.init(args=[])
    try:
        with tempfile.TemporaryDirectory() as tmp:
            return reference({name: declared_parameters(name, tmp) for name in NODES})
    finally:
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    """Print the reference, or write it to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="file to write (default: standard output)")
    args = parser.parse_args(argv)
    try:
        if args.out is not None:  # refused before the nodes are started, in one line
            check_output_file(args.out, "--out", "parameter reference")
        text = generate()
        if args.out is None:
            sys.stdout.write(text)
            return 0
        with written_atomically(args.out, "--out") as stream:  # whole, or the file as it was
            stream.write(text.encode())
    except (ValueError, OSError) as error:
        print(f"parameter_reference: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
