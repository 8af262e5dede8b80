"""Small helpers shared by the command lines (JSON output, numbers in tables, a seed)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np


def json_default(value: Any) -> Any:
    """``json.dumps`` ``default=``: numpy scalars as Python numbers, paths as text."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def number(value: float | None, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits; ``-`` for none or NaN, ``never`` for inf."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "never"
    return f"{value:.{digits}g}"


def seed(text: str) -> int:
    """A ``--seed`` option's value: a whole number >= 0 (numpy's generators take no other).

    An option type: a bad value is argparse's one-line error, naming the option.
    """
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return value


class GivenOption(argparse.Action):
    """Store an option's value as ``store`` does, and note that it was given.

    ``args.given`` is the set of the destinations (``room``, ``calibration_s``) of the
    options of this kind typed on the command line, whatever their value: a default typed
    out counts as given. The value of an option not given is its real default, as ``--help`` says.
    The parser must start the set empty (``set_defaults(given=frozenset())``).
    """

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:  # fmt: skip
        setattr(namespace, self.dest, values)
        namespace.given = frozenset(getattr(namespace, "given", frozenset()) | {self.dest})
