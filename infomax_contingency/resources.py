"""Locate the package's data files (config/, policies/, launch/, package.xml).

Three layouts are supported, searched in this order:

1. an ament install (``colcon build``, or a ROS distribution package): the share
   directory reported by ``ament_index_python.get_package_share_directory``;
2. a plain ``pip install .`` into an environment: ``<sys.prefix>/share/<package>``;
3. the source tree (the repository root, parent of this package's directory), which is
   what ``pip install -e .`` leaves, since an editable install copies no data files.

A location is used for a file only if it actually holds that file, so an install that
lacks a file (an older build, say) falls through to the next location. This module
imports no rclpy.
"""

from __future__ import annotations

import sys
from pathlib import Path

PACKAGE_NAME = "infomax_contingency"


def source_root() -> Path:
    """Return the source tree's root: the directory that holds this package's directory."""
    return Path(__file__).resolve().parent.parent


def _ament_share() -> Path | None:
    """Return the share directory from the ament index, or None if it has none."""
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(PACKAGE_NAME))
    except (LookupError, OSError, ValueError):
        # PackageNotFoundError is a KeyError; an unset AMENT_PREFIX_PATH is an OSError.
        return None


def candidate_directories() -> list[Path]:
    """Return the directories searched for data files, most preferred first."""
    candidates = []
    ament = _ament_share()
    if ament is not None:
        candidates.append(ament)
    candidates.append(Path(sys.prefix) / "share" / PACKAGE_NAME)
    candidates.append(source_root())
    unique: list[Path] = []
    for directory in candidates:
        if directory not in unique:
            unique.append(directory)
    return unique


def _search(relative: Path) -> Path:
    """Return the first candidate directory joined with ``relative`` that exists."""
    searched = []
    for directory in candidate_directories():
        path = directory / relative
        if path.exists():
            return path
        searched.append(str(path))
    raise FileNotFoundError(
        f"{PACKAGE_NAME}: cannot find '{relative}'. Searched: {', '.join(searched)}. "
        "Build with colcon and source the install, export AMENT_PREFIX_PATH, "
        "or run from a source checkout."
    )


def share_directory() -> Path:
    """Return the package's share directory: the first candidate that holds package.xml.

    Raises:
        FileNotFoundError: if no candidate directory holds ``package.xml``.
    """
    return _search(Path("package.xml")).parent


def resource_path(*parts: str | Path) -> Path:
    """Return the path of a data file, e.g. ``resource_path("config", "robot.yaml")``.

    Args:
        *parts: path components relative to the share directory (at least one).

    Raises:
        ValueError: if no part is given, or the path is absolute or leaves the directory.
        FileNotFoundError: if no candidate directory holds the file; the message lists
            every place searched.
    """
    if not parts:
        raise ValueError("resource_path() needs at least one path component")
    relative = Path(*parts)
    if relative.is_absolute() or ".." in relative.parts:
        raise ValueError(f"resource_path() takes a path inside the package, got '{relative}'")
    return _search(relative)
