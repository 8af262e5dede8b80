"""The package's layers: imports only go down, and rclpy stays in the ROS shell.

Every module of ``infomax_contingency`` is parsed (not imported) and each of its
imports of the package, at module level or inside a function, is checked against the
layer table below. A new module in an unknown place fails here until it is given a layer.
The same parse keeps the code in bounds a reader can hold: a module of at most
``LONGEST_MODULE_LINES`` lines, a function of at most ``LONGEST_FUNCTION_LINES``, a class of
at most ``MOST_METHODS`` methods; ruff (``ruff.toml``) bounds branches and statements.
Today's exceptions are listed by name below, and a listed name that is back in bounds (or
gone) fails too, so the lists only shrink.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parent.parent / "infomax_contingency"

BASE = ("resources", "errors", "limits", "lifetime")
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


def _big_classes(path: Path) -> list[str]:
    """'name (N methods)' of each class in the file with more than MOST_METHODS methods."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            methods = sum(isinstance(b, ast.FunctionDef | ast.AsyncFunctionDef) for b in node.body)
            if methods > MOST_METHODS:
                found.append(f"{node.name} ({methods} methods)")
    return found


def _ruff_exceptions(path: Path) -> set[str]:
    """Functions and classes whose head carries a noqa of a bound (C901, PLR0915, PLR0904)."""
    lines = path.read_text().split("\n")
    tree = ast.parse("\n".join(lines), filename=str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            head = " ".join(lines[node.lineno - 1 : node.body[0].lineno - 1])
            if any(f"noqa: {rule}" in head for rule in ("C901", "PLR0915", "PLR0904")):
                found.add(node.name)
    return found


MODULES = _modules()

LONGEST_FUNCTION_LINES = 60
"""Longest function (decorators excluded, docstring included) a module of the package may
have; a node's parameters go in a config dataclass read by one function per group."""

LONGEST_MODULE_LINES = 600
"""Longest module of the package, lines."""

MOST_METHODS = 20
"""Most methods (public or not) a class of the package may have."""

LONG_FUNCTIONS = {
    "infomax_contingency.core.learning": {"learn"},
    "infomax_contingency.core.solver": {"bellman_layer"},
}
"""Functions over LONGEST_FUNCTION_LINES today, by module (the list may only shrink)."""

LONG_MODULES: set[str] = set()
"""Modules over LONGEST_MODULE_LINES today (the list may only shrink)."""

BIG_CLASSES: dict[str, set[str]] = {}
"""Classes over MOST_METHODS methods today, by module (the list may only shrink)."""

RUFF_EXCEPTIONS = {
    "infomax_contingency.audio.threshold_file": {"load_threshold"},
    "infomax_contingency.audio.wav": {"open_wav_info"},
    "infomax_contingency.cli.sessions": {"_check_replay"},
    "infomax_contingency.core.learning": {"learn"},
    "infomax_contingency.eval.rooms.config": {"__post_init__"},
    "infomax_contingency.nodes.runtime": {"run_nodes"},
    "infomax_contingency.sim.room_config": {"__post_init__"},
}
"""Functions that carry a ``noqa`` of a bound of ruff.toml (C901, PLR0915, PLR0904) today,
by module (the list may only shrink)."""


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


def _names(found: list[str]) -> set[str]:
    return {entry.split(" (")[0] for entry in found}


def _beyond(found: dict[str, set[str]], listed: dict[str, set[str]]) -> list[str]:
    """'module: name' of each name in ``found`` that ``listed`` does not list."""
    return [f"{module}: {n}" for module, names in found.items()
            for n in sorted(names - listed.get(module, set()))]  # fmt: skip


def test_no_function_is_longer_than_the_limit() -> None:
    long = {name: _names(_long_functions(path)) for name, path in MODULES}
    new = _beyond(long, LONG_FUNCTIONS)
    assert not new, f"functions over {LONGEST_FUNCTION_LINES} lines: {new}"
    back = _beyond(LONG_FUNCTIONS, long)
    assert not back, f"in bounds (or gone) now: take them off LONG_FUNCTIONS: {back}"


def test_no_module_is_longer_than_the_limit() -> None:
    long = {name for name, path in MODULES if path.read_text().count("\n") > LONGEST_MODULE_LINES}
    assert long <= LONG_MODULES, f"modules over {LONGEST_MODULE_LINES} lines: {long - LONG_MODULES}"
    assert LONG_MODULES <= long, f"in bounds now: take them off LONG_MODULES: {LONG_MODULES - long}"


MIC_NODE_LINES = 400
"""Longest mic_node module: it wires windows, bit source and topics; the logic lives in
its configuration (mic_config), its bit-source controls (mic_bits) and below."""


def test_mic_node_stays_a_thin_node() -> None:
    path = dict(MODULES)["infomax_contingency.nodes.mic_node"]
    assert path.read_text().count("\n") <= MIC_NODE_LINES


def test_no_class_has_more_methods_than_the_limit() -> None:
    big = {name: _names(_big_classes(path)) for name, path in MODULES}
    new = _beyond(big, BIG_CLASSES)
    assert not new, f"classes over {MOST_METHODS} methods: {new}"
    back = _beyond(BIG_CLASSES, big)
    assert not back, f"in bounds now: take them off BIG_CLASSES: {back}"


SUBJECT_PACKAGES = ("eval/experiments", "eval/rooms")
"""Packages split into one module per subject whose ``__init__`` re-exports every public
name of its modules (``from infomax_contingency.eval import experiments`` sees them all)."""


def _public_names(path: Path) -> set[str]:
    """Public functions, classes and constants defined at the top of a module."""
    names = set()
    for node in ast.parse(path.read_text(), filename=str(path)).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
    return {name for name in names if not name.startswith("_")}


def _exported(init: Path) -> set[str]:
    """The names listed in a package's ``__all__``."""
    for node in ast.parse(init.read_text(), filename=str(init)).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
        ):
            return {element.value for element in node.value.elts}
    return set()


@pytest.mark.parametrize("package", SUBJECT_PACKAGES)
def test_a_subject_package_reexports_its_public_names(package: str) -> None:
    directory = PACKAGE_DIR / package
    defined = {
        f"{path.stem}.{name}"
        for path in sorted(directory.glob("*.py"))
        if path.name != "__init__.py"
        for name in _public_names(path)
    }
    exported = _exported(directory / "__init__.py")
    missing = sorted(entry for entry in defined if entry.split(".")[1] not in exported)
    assert len(defined) > 10 and not missing, f"{package}/__init__.py does not export {missing}"


def test_the_ruff_bound_exceptions_only_shrink() -> None:
    found = {name: _ruff_exceptions(path) for name, path in MODULES}
    assert {name: names for name, names in found.items() if names} == RUFF_EXCEPTIONS


def test_the_bound_checks_see_what_they_bound(tmp_path: Path) -> None:
    big = tmp_path / "big.py"
    methods = "".join(f"    def m{i}(self):\n        pass\n" for i in range(MOST_METHODS + 1))
    big.write_text(f"class Big:\n{methods}\n\ndef f():  # noqa: C901\n    pass\n")
    assert _big_classes(big) == [f"Big ({MOST_METHODS + 1} methods)"]
    assert _ruff_exceptions(big) == {"f"}


def test_the_length_check_sees_a_long_function(tmp_path: Path) -> None:
    long = tmp_path / "long.py"
    body = "".join(f"    x{i} = {i}\n" for i in range(LONGEST_FUNCTION_LINES))
    long.write_text(f"def short():\n    pass\n\n\ndef long():\n{body}")
    assert _long_functions(long) == [f"long ({LONGEST_FUNCTION_LINES + 1} lines, line 5)"]
