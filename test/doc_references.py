"""What the docs name, checked against the repository: files, commands, parameters, topics.

Pragmatic rules, in the forms the docs use (`test/test_docs.py` runs them on README.md
and docs/*.md):

- **Files**: a backticked or code-block path whose first part is a directory of the
  repository (``config/robot.yaml``) or of the package (``core/model.py``), a bare
  ``name.py`` / ``name.md``, a test module or test named as ``test_x``, a Markdown link,
  or a dotted name under the package
  (``infomax_contingency.audio.threshold.kmeans_split``, ``core.model.Statistic``) must
  exist. Paths with placeholders (``FILE``, ``<node>``, ``*``), absolute or home paths
  are examples, not checked.
- **Commands**: ``infomax-contingency CMD`` (and ``DEMO_ARGS="CMD ..."``, and a backticked
  span that starts with a subcommand) names a subcommand and its options; ``ros2 run
  infomax_contingency EXE`` an executable and its ``-p NAME:=`` parameters; ``ros2 launch
  infomax_contingency FILE`` a launch file and its ``ARG:=`` arguments; ``ros2 param
  get|set|describe /NODE NAME`` a node's parameter (``set``: a live one, unless the line
  says it is refused); ``ros2 topic ... /TOPIC`` a topic;
  ``ros2 service call /NODE/SRV`` a service; ``make TARGET`` a Makefile target; a span
  that is only ``NAME:=VALUE`` a launch argument of some launch file or a parameter.
- **Parameters**: ``NODE:NAME:=``, ``NODE.NAME``, "NODE's `NAME`" name a parameter of
  NODE (``NODE.NAME`` may also be an attribute of the node's module; "NODE's `NAME`" a
  topic or a value of one of NODE's choice parameters); a table header cell that is a
  backticked snake_case name, and the first column of a table headed "parameter", name
  parameters of some node.
- **Topics**: the first column of a table headed "topic"; **commands**: of one headed
  "command".

The known topics, services and key parameters come from the README's "ROS API" tables
(:func:`ros_api_tables`), which ``test_docs`` checks against the running nodes; the
declared parameters from docs/PARAMETERS.md, which it checks against the nodes' code.
"""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "infomax_contingency"

API_ROWS = ("subscribes", "publishes", "services", "key parameters")
"""The rows of a node's ROS API table in the README, in order."""


@dataclass
class NodeApi:
    """One node's ROS API table: the names in each row."""

    subscribes: list[str] = field(default_factory=list)
    publishes: list[str] = field(default_factory=list)
    services: list[str] = field(default_factory=list)
    parameters: list[str] = field(default_factory=list)


def _backticked(cell: str) -> list[str]:
    """The backticked names of a table cell, outside parentheses and links."""
    cell = re.sub(r"\[([^\]]*)\]\([^)]*\)", "", cell)
    while re.search(r"\([^()]*\)", cell):
        cell = re.sub(r"\([^()]*\)", "", cell)
    return re.findall(r"`([^`]+)`", cell)


def ros_api_tables(text: str, nodes: tuple[str, ...]) -> dict[str, NodeApi]:
    """Node -> its ROS API table, from headings ``### `node` ...`` followed by a table."""
    tables: dict[str, NodeApi] = {}
    current: str | None = None
    for line in text.splitlines():
        heading = re.match(r"#{2,4} `(\w+)`", line)
        if heading:
            current = heading.group(1) if heading.group(1) in nodes else None
            continue
        if current is None or not line.startswith("|"):
            continue
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        row = cells[0].strip("*").lower()
        if row in API_ROWS and len(cells) > 1:
            api = tables.setdefault(current, NodeApi())
            names = _backticked(cells[1])
            attribute = "parameters" if row == "key parameters" else row
            getattr(api, attribute).extend(names)
    return tables


def _per_node(text: str, row: str) -> dict[str, set[str]]:
    """docs/PARAMETERS.md -> node -> the comma-separated words ``row`` captures in its rows.

    The "Every node" section's words are added to each node's.
    """
    sections: dict[str, set[str]] = {}
    current = ""
    for line in text.splitlines():
        if line.startswith("## "):
            current = line[3:].strip()
            sections[current] = set()
        elif current and (found := re.search(row, line)):
            sections[current] |= {word.strip() for word in found.group(1).split(",")}
    common = sections.pop("Every node", set())
    return {node: names | common for node, names in sections.items()}


def parameter_reference(text: str) -> dict[str, set[str]]:
    """docs/PARAMETERS.md -> node -> declared parameter names."""
    return _per_node(text, r"^\| `(\w+)` \|")


def choice_values(text: str) -> dict[str, set[str]]:
    """docs/PARAMETERS.md -> node -> the values its choice parameters allow ("one of ...")."""
    return _per_node(text, r"\| one of ([\w, +-]+) \|")


def live_parameters(text: str) -> dict[str, set[str]]:
    """docs/PARAMETERS.md -> node -> the parameters marked live."""
    return _per_node(text, r"^\| `(\w+)` \|(?:[^|]*\|){3} live \|")


@dataclass
class Repository:
    """What exists: files, executables, CLI, launch arguments, parameters, topics."""

    parameters: dict[str, set[str]]
    """Node -> declared parameters."""
    topics: set[str]
    services: dict[str, set[str]]
    """Node -> services (relative names, ``reset`` for ``~/reset``)."""
    executables: set[str]
    make_targets: set[str]
    cli: argparse.ArgumentParser
    launch_arguments: dict[str, set[str]]
    tracked_names: set[str]
    choices: dict[str, set[str]] = field(default_factory=dict)
    """Node -> the values of its choice parameters (``calibrate``, ``vad``, ...)."""
    live: dict[str, set[str]] = field(default_factory=dict)
    """Node -> the parameters ``ros2 param set`` may change."""

    @property
    def all_parameters(self) -> set[str]:
        return set().union(*self.parameters.values())


def console_scripts() -> set[str]:
    """The executables setup.py installs."""
    return set(re.findall(r'"([\w-]+) = infomax_contingency', (ROOT / "setup.py").read_text()))


def make_targets() -> set[str]:
    return set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.MULTILINE))


def launch_arguments() -> dict[str, set[str]]:
    """Launch file name -> the arguments it declares."""
    return {
        path.name: set(re.findall(r"DeclareLaunchArgument\(\s*[\"'](\w+)[\"']", path.read_text()))
        for path in (ROOT / "launch").glob("*.launch.py")
    }


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {option for action in parser._actions for option in action.option_strings}


# ------------------------------------------------------------------ where names stand


def code_spans(text: str) -> Iterator[str]:
    """Inline code spans, and the logical lines of fenced code blocks (continuations joined)."""
    in_block = False
    pending = ""
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            in_block = not in_block
            pending = ""
            continue
        if in_block:
            pending += line.rstrip()
            if pending.endswith("\\"):
                pending = pending[:-1] + " "
                continue
            yield pending
            pending = ""
        else:
            yield from re.findall(r"`([^`\n]+)`", line)


def _strip_comment(command: str) -> str:
    return re.split(r"\s#\s|\s#$", command)[0]


def _words(command: str) -> list[str]:
    try:
        return shlex.split(_strip_comment(command), posix=True)
    except ValueError:
        return _strip_comment(command).split()


def _commands(span: str) -> Iterator[list[str]]:
    """Each command of a span (split at ``&&``, ``;``, ``|``), as words."""
    for part in re.split(r"&&|;|\|(?!\|)", span):
        words = _words(part)
        if words:
            yield words


# ------------------------------------------------------------------ the checks


PLACEHOLDER = re.compile(r"(^|[/._-])[A-Z][A-Z0-9_]*($|[/.:,;])|[<>*{}$~]|\.\.\.")


def _is_placeholder(token: str) -> bool:
    return bool(PLACEHOLDER.search(token))


def _top_level() -> set[str]:
    package = {p.name for p in (ROOT / PACKAGE).iterdir() if p.is_dir() and p.name[0] != "_"}
    repo = {p.name for p in ROOT.iterdir() if p.name not in (".git", ".venv")}
    return package | repo


def _resolves_in_package(dotted: str) -> bool:
    """``audio.threshold.kmeans_split`` (or with the package prefix): module + attributes."""
    parts = dotted.split(".")
    if parts[0] != PACKAGE:
        parts = [PACKAGE, *parts]
    for cut in range(len(parts), 1, -1):
        try:
            module = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        target: object = module
        for attribute in parts[cut:]:
            if not hasattr(target, attribute):
                # a dataclass field or an instance attribute set in __init__
                annotations = getattr(target, "__annotations__", {})
                source = _source_of(target)
                if attribute in annotations or f"self.{attribute}" in source:
                    return True
                return False
            target = getattr(target, attribute)
        return True
    return False


def _source_of(target: object) -> str:
    import inspect

    try:
        return inspect.getsource(target)  # type: ignore[arg-type]
    except (OSError, TypeError):
        return ""


OUTPUT_OPTIONS = frozenset({"--out", "--plot", "--record", "--output", "-o"})
"""Options whose value is a file a command writes (an example, not a file to find)."""


def _inputs(span: str) -> list[str]:
    """The words of ``span``, less the values of :data:`OUTPUT_OPTIONS`."""
    words = span.split()
    return [word for before, word in zip(["", *words], words, strict=False)
            if before not in OUTPUT_OPTIONS]


def _defined_in_tests(name: str) -> bool:
    """A test function or helper ``name`` defined in some test module."""
    pattern = re.compile(rf"^\s*def {re.escape(name)}\(", re.MULTILINE)
    return any(pattern.search(path.read_text()) for path in (ROOT / "test").glob("*.py"))


def _file_exists(token: str, doc: Path, repo: Repository) -> bool:
    token = token.rstrip("/") or token
    for base in (ROOT, doc.parent, ROOT / PACKAGE):
        if (base / token).exists():
            return True
    return "/" not in token and token in repo.tracked_names


def missing_files(doc: Path, text: str, repo: Repository) -> list[str]:
    """Paths and dotted package names in ``text`` that name nothing in the repository."""
    top = _top_level()
    problems = []
    candidates = [piece for span in code_spans(text) for word in _inputs(span)
                  for piece in re.split(r"[=,()\"'\[\]]+|:=", word)]
    for raw in candidates:
        token = raw.strip(".,;:")
        if not token or _is_placeholder(token) or token.startswith(("/", "http", "-")):
            continue
        if not re.fullmatch(r"[\w.\-/]+", token):
            continue
        first = token.split("/")[0].split(".")[0]
        if "/" in token and first in top:
            if _file_exists(token, doc, repo):
                continue
            if "." in token and _resolves_in_package(token.replace("/", ".").removesuffix(".py")):
                continue
            problems.append(f"file `{token}`")
        elif "/" not in token and re.fullmatch(r"[\w-]+\.(py|md)", token):
            if not _file_exists(token, doc, repo):
                problems.append(f"file `{token}`")
        elif "/" not in token and "." in token and (first == PACKAGE or (
                first in top and (ROOT / PACKAGE / first).is_dir())):
            if not re.fullmatch(r"[\w.]+", token) or token.endswith((".py", ".md")):
                continue
            if not _resolves_in_package(token):
                problems.append(f"name `{token}`")
    for name in re.findall(r"`(test_\w+)`", text):
        if not (ROOT / "test" / f"{name}.py").exists() and not _defined_in_tests(name):
            problems.append(f"test `{name}`")
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        path = target.split("#")[0]
        if path and not path.startswith(("http", "mailto")) and not (doc.parent / path).exists():
            problems.append(f"link `{target}`")
    return problems


def _node_of(path: str, repo: Repository) -> str | None:
    """``/robot1/mic_node`` -> ``mic_node`` when it is a node of the package."""
    name = path.rstrip("/").split("/")[-1]
    return name if name in repo.parameters else None


def _check_parameter(node: str, name: str, repo: Repository, problems: list[str]) -> None:
    if name not in repo.parameters.get(node, set()):
        problems.append(f"parameter `{node}:{name}`")


def _check_cli(words: list[str], repo: Repository, problems: list[str]) -> None:
    """``words`` after ``infomax-contingency``: a subcommand and its options."""
    commands = subparsers(repo.cli)
    if not words or words[0].startswith("-") or _is_placeholder(words[0]):
        return
    if words[0] not in commands:
        problems.append(f"command `infomax-contingency {words[0]}`")
        return
    parser = commands[words[0]]
    rest = words[1:]
    experiments = subparsers(parser)
    if experiments and rest and not rest[0].startswith("-") and not _is_placeholder(rest[0]):
        if rest[0] not in experiments:
            problems.append(f"command `infomax-contingency {words[0]} {rest[0]}`")
            return
        parser = experiments[rest[0]]
    options = _options(parser)
    for word in rest:
        option = word.split("=")[0]
        if option.startswith("--") and option not in options:
            problems.append(f"option `infomax-contingency {words[0]} {option}`")


def _check_ros2(words: list[str], repo: Repository, problems: list[str]) -> None:
    """``words`` after ``ros2``."""
    if len(words) >= 3 and words[0] == "run" and words[1] == PACKAGE:
        exe = words[2]
        if not _is_placeholder(exe) and exe not in repo.executables:
            problems.append(f"executable `ros2 run {PACKAGE} {exe}`")
        for flag, value in zip(words, words[1:], strict=False):
            if flag == "-p" and ":=" in value:
                name = value.split(":=")[0]
                node, _, parameter = name.rpartition(":")
                node = node or exe
                if node in repo.parameters and not _is_placeholder(parameter):
                    _check_parameter(node, parameter, repo, problems)
    elif len(words) >= 3 and words[0] == "launch" and words[1] == PACKAGE:
        arguments = repo.launch_arguments.get(words[2])
        if arguments is None:
            problems.append(f"launch file `{words[2]}`")
            return
        for word in words[3:]:
            if ":=" in word and re.fullmatch(r"\w+", name := word.split(":=")[0]):
                if name not in arguments:
                    problems.append(f"launch argument `{words[2]} {name}:=`")
    elif len(words) >= 3 and words[0] == "param" and words[1] in ("get", "set", "describe"):
        node = _node_of(words[2], repo)
        if _is_placeholder(words[2]):
            pass
        elif node is None:
            problems.append(f"node `{words[2]}`")
        elif len(words) >= 4 and not _is_placeholder(words[3]):
            _check_parameter(node, words[3], repo, problems)
            declared = words[3] in repo.parameters.get(node, set())
            if words[1] == "set" and declared and words[3] not in repo.live.get(node, set()):
                problems.append(f"live parameter `{node}:{words[3]}`")
    elif len(words) >= 3 and words[0] == "topic" and words[1] in ("echo", "hz", "pub", "info"):
        named = next((word for word in words[2:] if not word.startswith("-")), "")
        topic = named.rstrip("/").split("/")[-1]
        if topic and not _is_placeholder(topic) and topic not in repo.topics:
            problems.append(f"topic `{named}`")
    elif len(words) >= 3 and words[0] == "service" and words[1] == "call":
        *_, node, service = words[2].split("/")
        if service not in repo.services.get(node, set()):
            problems.append(f"service `{words[2]}`")


def missing_commands(text: str, repo: Repository) -> list[str]:
    """Commands, options, parameters and topics in ``text`` that do not exist."""
    problems: list[str] = []
    cli_names = set(subparsers(repo.cli))
    for span in code_spans(text):
        if re.search(r"ros2 param set .*#.*refused", span):
            continue  # an example of a refusal
        for words in _commands(span):
            for index, word in enumerate(words):
                tail = words[index + 1:]
                if word.endswith("infomax-contingency"):
                    _check_cli(tail, repo, problems)
                elif word.startswith("DEMO_ARGS="):
                    _check_cli(_words(word.split("=", 1)[1]), repo, problems)
                elif word == "ros2":
                    _check_ros2(tail, repo, problems)
                elif word == "make" and tail and re.fullmatch(r"[a-z][\w-]*", tail[0]):
                    if tail[0] not in repo.make_targets:
                        problems.append(f"make target `{tail[0]}`")
                elif word.startswith(".venv/bin/") and index == 0:
                    exe = word.removeprefix(".venv/bin/")
                    if exe not in repo.executables and not (ROOT / word).exists():
                        problems.append(f"executable `{word}`")
            if words[0] in cli_names and len(words) > 1 and words[1].startswith("-"):
                _check_cli(words, repo, problems)
            if words[0] == "experiment" and len(words) > 1:
                _check_cli(words, repo, problems)
        bare = re.fullmatch(r"(\w+):=\S*", span.strip())
        arguments = set().union(*repo.launch_arguments.values()) | repo.all_parameters
        if bare and bare.group(1) not in arguments:
            problems.append(f"launch argument `{bare.group(1)}:=`")
        for node, name in re.findall(r"\b(\w+_node):(\w+):=", span):
            if node in repo.parameters and not _is_placeholder(name):
                _check_parameter(node, name, repo, problems)
    return problems


def missing_parameters_and_topics(text: str, repo: Repository) -> list[str]:
    """``NODE.NAME``, "NODE's `NAME`", and parameter or topic tables, against the code."""
    problems: list[str] = []
    for node, name in re.findall(r"`(\w+_node)\.(\w+)`", text):
        if node in repo.parameters and name not in repo.parameters[node]:
            if not _resolves_in_package(f"nodes.{node}.{name}"):
                problems.append(f"parameter `{node}.{name}`")
    for node, name in re.findall(r"\b(\w+_node)`?(?:'s)? `(\w+)`", text):
        known = repo.parameters.get(node, set()) | repo.topics | repo.choices.get(node, set())
        if node in repo.parameters and name not in known:
            problems.append(f"parameter `{name}` of {node}")
    header: list[str] | None = None
    for line in text.splitlines():
        if not line.startswith("|"):
            header = None
            continue
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if header is None:
            header = cells
            for cell in cells:
                name = re.fullmatch(r"`([a-z]+_[a-z_]+)`(?: .*)?", cell)
                if name and name.group(1) not in repo.all_parameters:
                    problems.append(f"parameter `{name.group(1)}` (table header)")
            continue
        if set(cells[0]) <= set("-: "):
            continue
        kind = header[0].lower()
        first = re.fullmatch(r"`([\w/~-]+)`", cells[0])
        if first is None:
            continue
        if kind == "parameter" and first.group(1) not in repo.all_parameters:
            problems.append(f"parameter `{first.group(1)}` (table)")
        elif kind == "topic" and first.group(1).lstrip("/") not in repo.topics:
            problems.append(f"topic `{first.group(1)}` (table)")
        elif kind == "command" and first.group(1) not in subparsers(repo.cli):
            problems.append(f"command `{first.group(1)}` (table)")
    return problems
