"""The package's layers: imports only go down, and rclpy stays in the ROS shell.

Every module of ``infomax_contingency`` is parsed (not imported) and each of its
imports of the package, at module level or inside a function, is checked against the
layer table below. A new module in an unknown place fails here until it is given a layer.
The same parse keeps functions short enough to read (``LONGEST_FUNCTION_LINES``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parent.parent / "infomax_contingency"

BASE = ("resources", "errors", "limits")
"""Top-level modules every layer may use."""

ALLOWED: dict[str, set[str]] = {
    "base": set(),
    "core": {"base", "core"},
    "audio": {"base", "core", "audio"},
    "sim": {"base", "core", "audio", "sim"},
    "eval": {"base", "core", "audio", "sim", "eval"},
    "nodes": {"base", "core", "audio", "sim", "nodes"},
    "testing": {"base", "core", "audio", "sim", "nodes", "testing"},
    "cli": {"base", "core", "audio", "sim", "eval", "nodes", "testing", "cli"},
}
"""Layer -> the layers its modules may import."""

ROS_LAYERS = {"nodes", "testing", "cli"}
"""Layers that may import rclpy and ROS message packages (cli only inside functions)."""

ROS_MODULES = ("rclpy", "std_msgs", "sensor_msgs", "std_srvs", "diagnostic_msgs", "rcl_interfaces")


def _layer_of(module: str) -> str:
    """Layer of ``infomax_contingency.<...>``."""
    parts = module.split(".")
    if len(parts) == 1:
        return "base"
    if parts[1] in BASE or parts[1] == "__init__":
        return "base"
    return parts[1]


def _modules() -> list[tuple[str, Path]]:
    found = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        relative = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
        parts = list(relative.parts)
        if parts[-1] == "__init__":
            parts.pop()
        found.append((".".join(parts), path))
    return found


def _imports(path: Path) -> list[tuple[str, bool, int]]:
    """(imported module, at module level?, line) of every import in the file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    top_level = {id(node) for node in tree.body}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, id(node) in top_level, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                raise AssertionError(f"{path}:{node.lineno}: relative import; use absolute imports")
            base = node.module or ""
            found.append((base, id(node) in top_level, node.lineno))
            # `from infomax_contingency.x import y` may import the module x.y
            found += [(f"{base}.{alias.name}", id(node) in top_level, node.lineno)
                      for alias in node.names if base.startswith("infomax_contingency")]
    return found


def _long_functions(path: Path) -> list[str]:
    """'name (N lines, line L)' of each function in the file longer than the limit."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return [
        f"{node.name} ({node.end_lineno - node.lineno + 1} lines, line {node.lineno})"
        for node in ast.walk(tree)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > LONGEST_FUNCTION_LINES
    ]


MODULES = _modules()

LONGEST_FUNCTION_LINES = 80
"""Longest function (decorators excluded, docstring included) a module of the package may
have; a node's parameters go in a config dataclass read by one function per source."""


def test_every_module_has_a_known_layer() -> None:
    unknown = [name for name, _ in MODULES if _layer_of(name) not in ALLOWED]
    assert not unknown, f"modules outside the layers {sorted(ALLOWED)}: {unknown}"


@pytest.mark.parametrize("name, path", MODULES, ids=[name for name, _ in MODULES])
def test_imports_go_down_the_layers(name: str, path: Path) -> None:
    layer = _layer_of(name)
    package_modules = {module for module, _ in MODULES}
    problems = []
    for imported, top_level, line in _imports(path):
        root = imported.split(".")[0]
        if root in ROS_MODULES and (
            layer not in ROS_LAYERS or (layer == "cli" and top_level)
        ):
            problems.append(f"line {line}: {layer} module imports {imported}")
        if root == "infomax_contingency" and imported in package_modules:
            target = _layer_of(imported)
            if target not in ALLOWED[layer]:
                problems.append(f"line {line}: {layer} imports {target} ({imported})")
            elif layer == "cli" and target in ("nodes", "testing") and top_level:
                # the offline commands must start without ROS: import the shell lazily
                problems.append(f"line {line}: cli imports {imported} at module level")
    assert not problems, f"{name}: " + "; ".join(problems)


def test_the_check_sees_an_upward_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("from infomax_contingency.nodes.runtime import run_node\nimport rclpy\n")
    imported = [module for module, _, _ in _imports(bad)]
    assert "infomax_contingency.nodes.runtime" in imported and "rclpy" in imported
    assert _layer_of("infomax_contingency.nodes.runtime") not in ALLOWED["core"]


def test_no_function_is_longer_than_the_limit() -> None:
    long = [f"{name}: {found}" for name, path in MODULES for found in _long_functions(path)]
    assert not long, f"functions over {LONGEST_FUNCTION_LINES} lines: {long}"


def test_the_length_check_sees_a_long_function(tmp_path: Path) -> None:
    long = tmp_path / "long.py"
    body = "".join(f"    x{i} = {i}\n" for i in range(LONGEST_FUNCTION_LINES))
    long.write_text(f"def short():\n    pass\n\n\ndef long():\n{body}")
    assert _long_functions(long) == [f"long ({LONGEST_FUNCTION_LINES + 1} lines, line 5)"]
