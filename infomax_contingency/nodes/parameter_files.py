"""What parameter files and ``-p`` arguments give that no node takes: named, not dropped.

A parameter file's keys that no node declares are ignored by rcl without a word (a
misspelled key, a misspelled node section), and so are ``-p`` values of a name the node
does not declare: :func:`undeclared_parameters` and
:func:`undeclared_command_line_parameters` name them, and ``runtime.run_nodes`` warns
about them once its nodes are up.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from typing import Any, Protocol

from infomax_contingency.limits import load_yaml
from infomax_contingency.nodes.entry import NODES as PACKAGE_NODES

SHARED_PARAMETERS = frozenset({"params", "fault_hold_s", "diagnostics_period_s", "use_sim_time"})
"""Parameters a ``/**`` section may give every node although some nodes do not declare
them (``config/robot.yaml``: the model, the diagnostics' timing)."""

WARNED_ELSEWHERE = frozenset({"threshold_file"})
"""Keys a node names itself when it does not use them (mic_node: a threshold file unread)."""

CHECKED_UNDECLARED = frozenset({"window_s"})
"""Keys no node declares that the nodes read themselves: ``window_s``, no parameter any
more, which a file may still set to the model's dt (:meth:`ParameterReader.model`)."""

_PARAMETERS_KEY = "ros__parameters"


def _ros_arguments(args: Sequence[str], flags: tuple[str, ...]) -> list[str]:
    """The value after each of ``flags`` in the ``--ros-args`` parts of ``args``."""
    values, inside = [], False
    for index, token in enumerate(args):
        if token == "--ros-args":
            inside = True
        elif token == "--":
            inside = False
        elif inside and token in flags and index + 1 < len(args):
            values.append(args[index + 1])
    return values


def params_files(args: Sequence[str]) -> list[str]:
    """The files named by ``--params-file`` in the ``--ros-args`` parts of ``args``."""
    return _ros_arguments(args, ("--params-file",))


def command_line_parameters(args: Sequence[str]) -> list[tuple[str, str]]:
    """``(node name or "", parameter)`` of each ``-p [NODE:]NAME:=VALUE`` in ``--ros-args``."""
    found = []
    for value in _ros_arguments(args, ("-p", "--param")):
        node, _, key = value.split(":=", 1)[0].rpartition(":")
        found.append((node, key))
    return found


def undeclared_command_line_parameters(args: Sequence[str], nodes: Sequence[DeclaringNode]
                                       ) -> list[tuple[DeclaringNode, str]]:  # fmt: skip
    """``-p`` parameters of ``args`` that their node does not take: ``(node, message)``.

    rcl ignores them silently. A setting of another bit source (mic_node's
    ``threshold_db`` while ``bit_source`` is ``background``) is named as such: a file may
    carry every source's settings, but a ``-p`` is meant for this run.
    """
    found = []
    for target, key in command_line_parameters(args):
        meant = [node for node in nodes if not target or target == node.get_name()]
        if any(node.has_parameter(key) for node in meant):
            continue  # without a node name it is every node's: one that takes it is enough
        if key in CHECKED_UNDECLARED or key in SHARED_PARAMETERS or key in WARNED_ELSEWHERE:
            continue
        knowing = [n for n in meant if key in getattr(getattr(n, "parameters", None), "known", ())]
        for node in knowing or meant[:1]:  # one line, by the node it was likely meant for
            name = ", ".join(n.get_fully_qualified_name() for n in ([node] if knowing else meant))
            found.append((node, f"-p {key} is a setting of another bit source than"
                                f" {name}'s (bit_source): ignored" if knowing
                          else f"-p {key} is not a parameter of {name}: ignored"))  # fmt: skip
    return found


def parameter_sections(document: Any) -> Iterator[tuple[str, list[str]]]:
    """``(node pattern, parameter names)`` of each section of a ROS parameter file.

    A section is the path of keys down to ``ros__parameters`` (``/**/mic_node``, or
    ``ns: {mic_node: ...}`` for ``/ns/mic_node``); nested parameters are dotted names,
    as rcl reads them (``a: {b: 1}`` is ``a.b``).
    """

    def names(tree: Any, prefix: str = "") -> Iterator[str]:
        for key, value in (tree or {}).items() if isinstance(tree, dict) else ():
            if isinstance(value, dict):
                yield from names(value, f"{prefix}{key}.")
            else:
                yield f"{prefix}{key}"

    def walk(tree: Any, path: tuple[str, ...]) -> Iterator[tuple[str, list[str]]]:
        if not isinstance(tree, dict):
            return
        for key, value in tree.items():
            if key == _PARAMETERS_KEY:
                tokens = [t for part in path for t in str(part).split("/") if t]
                yield "/" + "/".join(tokens), list(names(value))
            else:
                yield from walk(value, (*path, str(key)))

    yield from walk(document, ())


def section_matches(pattern: str, node_name: str) -> bool:
    """True when the section ``pattern`` applies to the node ``node_name`` (fully qualified).

    rcl's rule: ``*`` stands for one name token, ``**`` for any number of them.
    """
    regex = ""
    for token in pattern.strip("/").split("/"):
        regex += {"**": r"(/[^/]+)*", "*": r"/[^/]+"}.get(token, "/" + re.escape(token))
    return re.fullmatch(regex, node_name) is not None


class DeclaringNode(Protocol):
    """What :func:`undeclared_parameters` asks of a node (an rclpy ``Node`` has both)."""

    def get_fully_qualified_name(self) -> str: ...  # noqa: D102

    def has_parameter(self, name: str) -> bool: ...  # noqa: D102


def undeclared_parameters(files: Sequence[str], nodes: Sequence[DeclaringNode]
                          ) -> list[tuple[DeclaringNode | None, str]]:  # fmt: skip
    """What of the parameter ``files`` no node of ``nodes`` (one process's) takes.

    Returns ``(node, message)``: ``node`` the node a key was meant for but does not
    declare, or None for a section that matches no node of this process and is not
    named after a node of the package (``entry.NODES``): a misspelled node name (one
    named after a node of the package belongs to another process, as in a launch's one
    file). A key of a section for every node (its last name token a wildcard, ``/**``)
    counts only if none of ``nodes`` declares it and it is not one of
    :data:`SHARED_PARAMETERS`. Unreadable files are skipped (rcl refused them already).
    """
    found: list[tuple[DeclaringNode | None, str]] = []
    for file in files:
        try:
            sections = list(parameter_sections(load_yaml(file, "parameter file")))
        except (OSError, ValueError):
            continue  # rcl read it, this check cannot: it says nothing rather than fail
        for pattern, keys in sections:
            found += [(node, f"parameter file {file}: {message}")
                      for node, message in _section_findings(pattern, keys, nodes)]  # fmt: skip
    return found


def _takes(node: DeclaringNode, key: str) -> bool:
    """True when ``node`` declares ``key`` or knows it (:attr:`ParameterReader.known`)."""
    reader = getattr(node, "parameters", None)
    return node.has_parameter(key) or key in getattr(reader, "known", ())


def _section_findings(pattern: str, keys: list[str], nodes: Sequence[DeclaringNode]
                      ) -> list[tuple[DeclaringNode | None, str]]:  # fmt: skip
    """:func:`undeclared_parameters` of one section ``pattern`` holding ``keys``."""
    matched = [n for n in nodes if section_matches(pattern, n.get_fully_qualified_name())]
    last = pattern.rsplit("/", 1)[-1]
    wildcard = last in ("*", "**")
    if not matched:
        own = {node.get_fully_qualified_name().rsplit("/", 1)[-1] for node in nodes}
        if wildcard or last in PACKAGE_NODES or last in own or not keys:
            return []  # another namespace's, or another process's
        return [(None, f"section '{pattern}' matches no node (the package's nodes:"
                       f" {', '.join(PACKAGE_NODES)}); its parameters {', '.join(keys)} are"
                       " ignored")]  # fmt: skip
    found: list[tuple[DeclaringNode | None, str]] = []
    for key in (key for key in keys if key not in CHECKED_UNDECLARED):
        if wildcard:  # for every node: some take it, others need not
            shared = key in SHARED_PARAMETERS or any(_takes(n, key) for n in nodes)
            targets = [] if shared else matched
        else:
            targets = [n for n in matched if not _takes(n, key)]
        found += [(node, f"'{key}' (section '{pattern}') is not a parameter of"
                         f" {node.get_fully_qualified_name()}: ignored")
                  for node in targets]  # fmt: skip
    return found
