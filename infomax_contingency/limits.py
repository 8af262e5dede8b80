"""Cost checks made before the work: the memory this process may still take, and bounded YAML.

Every command and node that can be handed a size (a horizon, a number of steps, a file)
estimates what the work will cost and compares it with :func:`memory_budget` before it
starts, so an oversized request ends with one line instead of a MemoryError, an OOM kill
or a machine that swaps. The budget is the smallest of

* ``MemAvailable`` (``/proc/meminfo``): what the machine can give without swapping;
* the process's address-space limit (``ulimit -v``, ``RLIMIT_AS``) less the address
  space it already maps (``VmSize``);
* the memory limit of its control group less what the group uses (cgroup v2
  ``memory.max`` / ``memory.current`` or v1 ``memory.limit_in_bytes`` /
  ``memory.usage_in_bytes``, the process's own group and every group above it).

Estimates are Python integers (no overflow whatever the request); :func:`format_bytes`,
:func:`format_number` and :func:`as_float` print them without an OverflowError.

:func:`load_yaml` reads a YAML file after bounding its size (a regular file only: a
device or FIFO has no size to check), its nesting depth (a 100,000-deep file would
otherwise end the parser in a RecursionError) and what its aliases expand to, as the
policy tables' metadata JSON is bounded; :func:`read_text_capped` is its bounded read,
for other small text files, and :func:`short_repr` quotes a value in a message.

Files a command writes are checked the same way before the work
(:func:`check_output_file`) and written whole or not at all (:func:`written_atomically`):
nothing but a regular file at the path is ever written over — a device, a FIFO (a write
to it would never end), a socket, a directory or a symbolic link is refused in one line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import reprlib
import resource
import stat
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

MAX_YAML_BYTES = 1 << 16
"""Largest YAML file read, bytes (model parameters, threshold files: well under 1 KB)."""
MAX_YAML_DEPTH = 8
"""Deepest nesting of mappings and sequences in a YAML file read (real files: 2)."""
MAX_YAML_NODES = 1 << 17
"""Most values (mappings, sequences, keys, scalars) a YAML file may expand to, aliases
followed: more than a file of :data:`MAX_YAML_BYTES` can hold written out (an alias
bomb of 454 bytes expands to 10^7)."""
UNWRITABLE_ROOTS = ("/proc", "/sys", "/dev")
"""Places no command writes a file to (the kernel's interfaces and the devices)."""
WRITTEN_FILE_MODE = 0o644
"""Permissions of a file :func:`written_atomically` writes (read by all, as the tables)."""
NO_LIMIT = 1 << 60
"""A limit at or above this (1 EiB) is no limit (cgroup v1 writes 2^63 - 4096 for none)."""


@dataclasses.dataclass(frozen=True)
class MemoryBudget:
    """The memory this process may still take.

    Attributes:
        bytes: the smallest of the limits (module docstring), bytes (>= 0).
        source: which limit that is, for a message (``"available memory"``,
            ``"ulimit -v"``, ``"cgroup memory limit"``).
    """

    bytes: int
    source: str


def _kilobytes_field(path: Path, field: str) -> int | None:
    """``field`` of a ``/proc`` file in ``Name:  123 kB`` lines, in bytes; None if unknown.

    ``MemAvailable`` of ``/proc/meminfo``: what the machine can give without swapping;
    ``VmSize`` of ``/proc/self/status``: the address space this process maps now.
    """
    try:
        for line in path.read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    if text == "max":
        return NO_LIMIT
    try:
        return int(text)
    except ValueError:
        return None


def _cgroup_dirs(root: Path, relative: str) -> list[Path]:
    """The group's directory under ``root`` and each one above it (those that exist)."""
    parts = [part for part in relative.strip("/").split("/") if part]
    dirs = [root.joinpath(*parts[:n]) for n in range(len(parts), -1, -1)]
    return [d for d in dirs if d.is_dir()]


def cgroup_headroom(cgroup_root: Path = Path("/sys/fs/cgroup"),
                    self_cgroup: Path = Path("/proc/self/cgroup")) -> int | None:
    """Bytes this process's control groups still allow (the tightest), or None if unlimited."""
    try:
        lines = self_cgroup.read_text().splitlines()
    except OSError:
        return None
    headrooms = []
    for line in lines:
        hierarchy, _, rest = line.partition(":")
        controllers, _, relative = rest.partition(":")
        if hierarchy == "0" and controllers == "":  # cgroup v2
            root, limit_file, usage_file = cgroup_root, "memory.max", "memory.current"
        elif "memory" in controllers.split(","):  # cgroup v1
            root, limit_file, usage_file = cgroup_root / "memory", "memory.limit_in_bytes", \
                "memory.usage_in_bytes"
        else:
            continue
        for directory in _cgroup_dirs(root, relative):
            limit = _read_int(directory / limit_file)
            usage = _read_int(directory / usage_file)
            if limit is not None and limit < NO_LIMIT:
                headrooms.append(max(0, limit - (usage or 0)))
    return min(headrooms) if headrooms else None


def memory_budget(meminfo: Path = Path("/proc/meminfo"),
                  status: Path = Path("/proc/self/status"),
                  cgroup_root: Path = Path("/sys/fs/cgroup"),
                  self_cgroup: Path = Path("/proc/self/cgroup")) -> MemoryBudget:
    """The memory this process may still take (module docstring); the paths are for tests.

    Raises:
        OSError: no limit could be read at all (no ``/proc``): one line, asking for one.
    """
    candidates: list[MemoryBudget] = []
    available = _kilobytes_field(meminfo, "MemAvailable")
    if available is not None:
        candidates.append(MemoryBudget(available, "available memory"))
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        candidates.append(MemoryBudget(max(0, soft - (_kilobytes_field(status, "VmSize") or 0)),
                                       f"ulimit -v {soft // 1024}"))
    headroom = cgroup_headroom(cgroup_root, self_cgroup)
    if headroom is not None:
        candidates.append(MemoryBudget(headroom, "cgroup memory limit"))
    if not candidates:
        raise OSError("cannot tell how much memory is available (no /proc/meminfo)")
    return min(candidates, key=lambda budget: budget.bytes)


def as_float(value: int | float) -> float:
    """``value`` as a float, ``inf`` when too large for one (never an OverflowError)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def format_number(value: int | float) -> str:
    """3 significant digits, ``e`` notation from 10^6 on: ``512``, ``1.5e+07``, ``4.2e+400``.

    Integers of any size (a float cannot hold 10^400) are formatted from their digits.
    """
    if isinstance(value, int) and abs(value) >= 10**300:
        digits = str(abs(value))
        mantissa = int(digits[:4]) / 1000
        return f"{'-' if value < 0 else ''}{mantissa:.3g}e+{len(digits) - 1}"
    return f"{value:.3g}"


def format_bytes(size: int | float) -> str:
    """``70 MiB``, ``13.7 GiB``, ``4.2e+30 PiB``: binary units, 3 significant digits, any size."""
    units = ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB")
    if isinstance(size, int) and size >= 1024 ** len(units):
        return f"{format_number(size // 1024 ** (len(units) - 1))} PiB"
    value = float(size)
    for unit in units:
        if value < 1024 or unit == "PiB":
            break
        value /= 1024
    return f"{value:.3g} {unit}"


def refuse_over_budget(needed_bytes: int, what: str, how_to_shrink: str = "",
                       error: type[ValueError] = ValueError) -> None:
    """``error`` (one line) when ``what`` would need more memory than :func:`memory_budget`.

    Args:
        needed_bytes: the estimate, bytes (any size).
        what: the work, for the message (``"plot 100000000 steps"``).
        how_to_shrink: advice appended to the message (``"give fewer --steps"``).
        error: the ValueError subclass raised (``AudioError`` for audio).
    """
    budget = memory_budget()
    if needed_bytes > budget.bytes:
        advice = f"; {how_to_shrink}" if how_to_shrink else ""
        raise error(f"refusing to {what}: it needs about {format_bytes(needed_bytes)} of"
                         f" memory, more than {format_bytes(budget.bytes)} ({budget.source})"
                         f"{advice}")


def bracket_depth(text: str) -> int:
    """Deepest nesting of ``[`` / ``{`` in text, in linear time.

    Quotes and comments are counted too: an upper bound of a YAML file's flow nesting.
    """
    depth = deepest = 0
    for char in text:
        if char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}" and depth:
            depth -= 1
    return deepest


def yaml_depth(text: str) -> int:
    """Deepest nesting of mappings and sequences in YAML text (parser events, no recursion).

    The parser takes time quadratic in the flow nesting (100,000 ``[``: two minutes), so
    call it only on text whose :func:`bracket_depth` is bounded.
    """
    import yaml

    depth = deepest = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            deepest = max(deepest, depth)
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
    return deepest


def _file_kind(mode: int) -> str:
    """What a file that is not a regular one is, for a message (``"a device"``)."""
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
             (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link"))
    return next((name for test, name in kinds if test(mode)), "an unknown kind of file")


def read_bytes_capped(path: str | Path, what: str, max_bytes: int = MAX_YAML_BYTES) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` bytes.

    Symlinks are followed; a directory, device, FIFO or socket is refused without being
    read (a FIFO is opened non-blocking, so it cannot hang), and at most ``max_bytes`` + 1
    bytes are read, so a file that grows while it is read cannot exceed the cap.

    Raises:
        FileNotFoundError: the file does not exist (the caller names it).
        ValueError: not a regular file, unreadable, or larger than ``max_bytes`` — one
            line, starting with ``what`` and the path.
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise
    except OSError as error:
        raise ValueError(f"cannot read {what} {path}: {error.strerror or error}") from None
    try:
        mode, size = os.fstat(fd).st_mode, os.fstat(fd).st_size
        if not stat.S_ISREG(mode):
            raise ValueError(f"{what} {path} is refused: it is {_file_kind(mode)}, not a"
                             " regular file; give the path of a file")
        if size > max_bytes:
            raise ValueError(f"{what} {path} is refused: it holds {size:,} bytes"
                             f" (at most {max_bytes:,})")
        with os.fdopen(fd, "rb", closefd=False) as stream:
            data = stream.read(max_bytes + 1)
    except OSError as error:
        raise ValueError(f"cannot read {what} {path}: {error.strerror or error}") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise ValueError(f"{what} {path} is refused: it holds more than {max_bytes:,} bytes"
                         " (it grew while it was read)")
    return data


def read_text_capped(path: str | Path, what: str, max_bytes: int = MAX_YAML_BYTES) -> str:
    """:func:`read_bytes_capped` decoded as UTF-8 (a byte that is not: one line, ValueError)."""
    data = read_bytes_capped(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ValueError(f"cannot read {what} {path}: it is not UTF-8 text (byte"
                         f" {error.start:,} is 0x{data[error.start]:02x})") from None


def finite(value: Any) -> bool:
    """``math.isfinite(value)``, but False (not OverflowError) for an integer beyond a float.

    YAML and JSON read any number of digits as an int; ``10**400`` is no more finite as
    a rate, a prior or a level than ``inf`` is.
    """
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def short_repr(value: Any, limit: int = 80) -> str:
    """``repr`` of ``value`` cut to about ``limit`` characters, in bounded time.

    Nested and aliased YAML values would otherwise print gigabytes: :mod:`reprlib` shows
    only the first few items of each level and a few levels. An integer of more digits
    than ``limit`` is named by its size (Python refuses to print one of 4,300 or more).
    """
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 3 * limit:
        digits = math.floor(value.bit_length() * math.log10(2)) + 1
        return f"{'-' if value < 0 else ''}an integer of about {digits:,} digits"
    shortener = reprlib.Repr()
    shortener.maxlevel, shortener.maxstring, shortener.maxother = 3, limit, limit
    shortener.maxlist = shortener.maxdict = shortener.maxtuple = shortener.maxset = 6
    text = shortener.repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def yaml_nodes(value: Any, cap: int = MAX_YAML_NODES) -> int:
    """Nodes of a loaded YAML value, aliases followed (a shared list counts each time).

    Stops counting past ``cap`` (the result is then ``cap + 1``), so an alias bomb or a
    recursive value costs at most ``cap`` steps.
    """
    count, stack = 0, [value]
    while stack and count <= cap:
        item = stack.pop()
        count += 1
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple, set)):
            stack.extend(item)
    return min(count, cap + 1)


def load_yaml(path: str | Path, what: str, max_depth: int = MAX_YAML_DEPTH,
              max_bytes: int = MAX_YAML_BYTES) -> Any:
    """``yaml.safe_load`` of a file, its size, nesting and expansion bounded.

    The file must be a regular file of at most ``max_bytes`` (:func:`read_text_capped`),
    nested at most ``max_depth`` deep (checked before the parser runs), and its value,
    aliases followed, at most :data:`MAX_YAML_NODES` nodes (:func:`yaml_nodes`).

    Raises:
        FileNotFoundError: the file does not exist (the caller names it).
        ValueError: not a regular file, unreadable, not UTF-8, too large, nested deeper
            than ``max_depth``, expanding past the node cap, or not YAML — one line,
            starting with ``what`` and the path.
    """
    import yaml

    path = Path(path)
    text = read_text_capped(path, what, max_bytes)
    try:
        depth = bracket_depth(text)
        if depth <= max_depth:
            depth = yaml_depth(text)
        if depth > max_depth:
            raise ValueError(f"{what} {path} is refused: it is nested {depth} deep"
                             f" (at most {max_depth})")
        value = yaml.safe_load(text)
    except (yaml.YAMLError, RecursionError) as error:
        detail = " ".join(str(error).split())[:300]
        raise ValueError(f"cannot read {what} {path}: not valid YAML: {detail}") from None
    except ValueError as error:  # an int Python will not convert (4,300 digits and more)
        if "integer string conversion" not in str(error):
            raise
        raise ValueError(f"cannot read {what} {path}: it holds a number of more than"
                         f" {sys.get_int_max_str_digits():,} digits") from None
    if yaml_nodes(value) > MAX_YAML_NODES:
        raise ValueError(f"{what} {path} is refused: its aliases expand to more than"
                         f" {MAX_YAML_NODES:,} values (write the values out, without"
                         " aliases)")
    return value


def refuse_unless_regular(path: str | Path, what: str) -> None:
    """Refuse to write over anything at ``path`` but a regular file (ValueError, one line).

    The path itself is looked at (``lstat``), not what a symbolic link points to: a write
    replaces what is there (a rename) or, into a FIFO, never ends, so a device, FIFO,
    socket, directory or symbolic link (even one to a regular file) is refused. A path
    with nothing at it passes. ``what`` starts the message (``--out``, ``threshold file``).
    """
    if not str(path):
        raise ValueError(f"{what}: the path is empty; give a file name")
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return  # nothing there, or a parent that is not a directory: the write says so
    if not stat.S_ISREG(mode):
        raise ValueError(f"{what} {path} is not a regular file (it is {_file_kind(mode)}):"
                         " nothing is written over it; give a new name or a regular file")


OUTPUT_SUFFIXES = {"figure": ".png"}
"""The ending a file of these ``contents`` must have (matplotlib writes PNG only here)."""


def check_output_file(path: str | Path, what: str, contents: str = "file") -> None:
    """Refuse, before any work, a path a command could not write ``contents`` to.

    Refused in one line starting with ``what`` (the option, ``--out``): a name without
    the ending of :data:`OUTPUT_SUFFIXES` (a figure that is no ``.png``); a path under
    :data:`UNWRITABLE_ROOTS`; anything there but a regular file
    (:func:`refuse_unless_regular`); a directory that cannot be made or written in (tried
    for real: a file is made there and removed); a file that is not writable. Missing
    parent directories are made.

    Raises:
        ValueError: the path is empty or something other than a regular file is there.
        OSError: the place cannot be written.
    """
    if not str(path):
        raise ValueError(f"{what}: the path is empty; give a file name")
    path = Path(path)
    suffix = OUTPUT_SUFFIXES.get(contents)
    if suffix is not None and path.suffix.lower() != suffix:  # ".png" alone has none
        raise ValueError(f"{what} {path}: a {contents} file's name must end in {suffix}")
    resolved = path.resolve()
    if any(resolved.is_relative_to(root) for root in UNWRITABLE_ROOTS):
        raise OSError(f"{what} {path}: /{resolved.parts[1]} is no place for a {contents}")
    refuse_unless_regular(path, what)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as error:
        raise OSError(f"{what} {path}: cannot write in {path.parent} ({error.strerror})") from None
    if path.exists() and not os.access(path, os.W_OK):
        raise OSError(f"{what} {path}: the file is not writable")


def check_output_files(*outputs: tuple[str, str | Path | None, str]) -> None:
    """:func:`check_output_file` of each ``(what, path, contents)`` asked for, then two apart.

    A ``None`` path is an output not asked for. Two outputs naming one file, however
    spelled (``r.wav`` and ``./d/../r.wav``, a directory reached through a symbolic link,
    a hard link), are refused in one line (ValueError): the second would overwrite the
    first.
    """
    given = [(what, Path(path)) for what, path, contents in outputs if path is not None]
    for what, path, contents in outputs:
        if path is not None:
            check_output_file(path, what, contents)
    for index, (what, path) in enumerate(given):
        for other_what, other in given[:index]:
            if _same_file(path, other):
                raise ValueError(f"{other_what} {other} and {what} {path} name one file:"
                                 " give each its own")


def _same_file(path: Path, other: Path) -> bool:
    """Whether two paths name one file, however spelled.

    ``r.wav`` and ``d/../r.wav``, a directory reached through a symbolic link, a hard link.
    """
    return path.resolve() == other.resolve() or (
        path.exists() and other.exists() and os.path.samefile(path, other))


def spec_file(spec: str | Path | None, prefixes: tuple[str, ...] = ("file:", "policy:")
              ) -> str | Path | None:  # fmt: skip
    """The file a specification names, or the specification as it is.

    ``file:T`` and ``policy:F``: the part after the prefix; any other specification or
    path unchanged (None stays None).
    """
    if spec is None or isinstance(spec, Path):
        return spec
    for prefix in prefixes:
        if spec.startswith(prefix):
            return spec[len(prefix):]
    return spec


def refuse_writing_over_inputs(outputs: tuple[tuple[str, str | Path | None], ...],
                               inputs: tuple[tuple[str, str | Path | None], ...]) -> None:
    """ValueError (one line) when an output names a file the command reads, however spelled.

    ``outputs`` and ``inputs``: ``(option, path)``; None, or an input that is no existing
    file (a parameter set's name, a controller's), is skipped. The output would replace
    the input (``calibrate --wav in.wav --out in.wav`` wrote the threshold over the
    recording).
    """
    for out_what, out in outputs:
        if out is None:
            continue
        out_path = Path(out)
        for in_what, source in inputs:
            if source is None or not Path(source).is_file():
                continue
            in_path = Path(source)
            if _same_file(out_path, in_path):
                raise ValueError(f"{out_what} {out_path} is the file {in_what} {in_path} reads:"
                                 " writing it would destroy the input; give another file")


@contextlib.contextmanager
def written_atomically(path: str | Path, what: str,
                       make_parents: bool = False) -> Iterator[BinaryIO]:
    """A binary stream whose bytes become the file ``path`` whole, or not at all.

    The bytes go to a temporary file beside ``path``, which is renamed over it at the end
    (permissions :data:`WRITTEN_FILE_MODE`); nothing at ``path`` but a regular file is
    written over (:func:`refuse_unless_regular`, before and again just before the
    rename). An error or an exception inside the ``with`` leaves ``path`` as it was.
    ``make_parents``: make the missing parent directories first.

    Raises:
        ValueError: something other than a regular file is at ``path``.
        OSError: the file could not be written (one line: ``what``, the path, the reason).
    """
    path = Path(path)
    refuse_unless_regular(path, what)
    try:
        if make_parents:
            path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    except OSError as error:
        raise OSError(f"cannot write {what} {path}: {error.strerror or error}") from None
    try:
        with os.fdopen(handle, "wb") as stream:
            yield stream
        os.chmod(temporary, WRITTEN_FILE_MODE)
        refuse_unless_regular(path, what)
        os.replace(temporary, path)
    except OSError as error:
        Path(temporary).unlink(missing_ok=True)
        raise OSError(f"cannot write {what} {path}: {error.strerror or error}") from None
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
