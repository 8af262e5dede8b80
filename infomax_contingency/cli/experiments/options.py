"""What the experiment commands share: option types, JSON output, the cache directory."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from infomax_contingency.cli.formatting import json_default


def int_list(text: str) -> list[int]:
    """``1,2,3`` as integers (an option type: a bad list is argparse's one-line error)."""
    try:
        values = [int(item) for item in text.split(",") if item.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected integers separated by commas, got {text!r}"
        ) from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one integer")
    return values


def name_list(text: str) -> list[str]:
    """``a,b`` as names, blanks dropped; at least one (an empty list ran nothing, exit 0)."""
    names = [item.strip() for item in text.split(",") if item.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected at least one name, got {text!r}")
    return names


def step_range(text: str) -> tuple[int, int]:
    """``FIRST-LAST`` (or one step ``N``) as a pair of steps."""
    first, _, last = text.partition("-")
    try:
        return int(first), int(last or first)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected FIRST-LAST steps, e.g. 18-24, got {text!r}"
        ) from None


def print_json(result: Any) -> None:
    """Print a result as indented JSON (numpy values as plain numbers)."""
    print(json.dumps(result, indent=1, default=json_default))


def cache_dir_of(args: argparse.Namespace) -> Path | None:
    """The ``--cache-dir`` option as a path, None for the default."""
    return Path(args.cache_dir) if args.cache_dir else None


def commas(values: Any) -> str:
    """A list default as it is typed on the command line: ``a,b,c``."""
    return ",".join(str(value) for value in values)


def add_parameter_sets_option(sub: argparse.ArgumentParser, default: Any) -> None:
    """``--params a,b``: the parameter sets an experiment runs on (``default``: names)."""
    sub.add_argument("--params", type=name_list, default=list(default),
                     help=f"sets (default {commas(default)})")
