"""Threshold files: a calibrated threshold in a small YAML file, written and read back.

:func:`save_threshold` writes what a calibration found (replaced atomically, and only
where nothing or a regular file is: never a device, FIFO or symbolic link);
:func:`load_threshold` reads the threshold of one level (``energy``, or another bit
source's level such as ``speech_band``) and refuses anything else in one line.
"""

from __future__ import annotations

import datetime
import math
import os
from pathlib import Path

import yaml

from infomax_contingency.audio.common import AudioError, check_positive_seconds, check_rate
from infomax_contingency.audio.threshold import ThresholdFit, check_threshold_db
from infomax_contingency.limits import finite, load_yaml, short_repr, written_atomically

THRESHOLD_FORMAT_VERSION = 1
"""Version of the threshold file layout written by :func:`save_threshold`."""

_REQUIRED_FIELDS = ("format_version", "threshold_db")


def save_threshold(
    path: str | os.PathLike[str],
    fit: ThresholdFit,
    *,
    window_s: float,
    rate: int,
    source: str,
    level: str = "energy",
) -> None:
    """Write a calibrated threshold to a small YAML file (replaced atomically).

    Args:
        path: file to write (nothing there yet, or a regular file: anything else, a
            symbolic link too, is refused; ``limits.written_atomically``); missing parent
            directories are created.
        fit: the k-means fit.
        window_s: window length used for the energies, seconds.
        rate: processing sample rate, Hz.
        source: where the calibration audio came from (file name, device, ...).
        level: the window level the threshold applies to: ``energy`` (the window
            energy; the field is then left out, as in files before levels existed) or
            another bit source's level (``speech_band``), written as the field ``level``.
    """
    window_s = check_positive_seconds(window_s, "window_s")
    rate = check_rate(rate)
    values = (fit.threshold_db, fit.low_mean_db, fit.high_mean_db)
    if not all(math.isfinite(v) for v in values):
        raise AudioError(f"cannot save a threshold fit with non-finite values: {fit}")
    record = {
        "format_version": THRESHOLD_FORMAT_VERSION,
        "threshold_db": float(fit.threshold_db),
        "window_s": window_s,
        "sample_rate_hz": rate,
        "low_mean_db": float(fit.low_mean_db),
        "high_mean_db": float(fit.high_mean_db),
        "n_low": int(fit.n_low),
        "n_high": int(fit.n_high),
        "source": str(source),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    if level != "energy":
        record["level"] = str(level)
    what = "energy" if level == "energy" else f"{level} level"
    text = (f"# Sound threshold: a window is 'sound' (y = 1) iff its {what} > threshold_db.\n"
            + yaml.safe_dump(record, sort_keys=False))
    path = Path(path)
    try:
        with written_atomically(path, "threshold file", make_parents=True) as stream:
            stream.write(text.encode("utf-8"))
    except (OSError, ValueError) as error:  # one line naming the file and why
        raise AudioError(str(error)) from None


def load_threshold(path: str | os.PathLike[str], level: str = "energy") -> float:  # noqa: C901
    """Read the threshold (dB) from a file written by :func:`save_threshold`.

    Args:
        path: the threshold file.
        level: the window level it must apply to (a file without the field ``level``
            applies to ``energy``).

    Raises:
        AudioError: the file is missing, is not a YAML mapping, has another format
            version, lacks ``format_version`` or ``threshold_db``, the threshold is
            not a finite number, or it applies to another level.
    """
    path = Path(path)
    try:
        record = load_yaml(path, "threshold file")
    except FileNotFoundError:
        raise AudioError(
            f"threshold file {path} does not exist; create it by calibrating on audio that "
            "contains both quiet and sound"
        ) from None
    except ValueError as exc:
        raise AudioError(str(exc)) from None
    if not isinstance(record, dict):
        raise AudioError(
            f"threshold file {path} must hold a YAML mapping with {', '.join(_REQUIRED_FIELDS)}; "
            f"got {type(record).__name__}"
        )
    for field in _REQUIRED_FIELDS:
        if field not in record:
            raise AudioError(f"threshold file {path} is missing the field '{field}'")
    version = record["format_version"]
    if isinstance(version, bool) or version != THRESHOLD_FORMAT_VERSION:
        raise AudioError(
            f"threshold file {path} has format_version {short_repr(version)}; this package"
            " reads "
            f"format_version {THRESHOLD_FORMAT_VERSION}. Recalibrate to rewrite it."
        )
    file_level = record.get("level", "energy")
    if file_level != level:
        shown_level = file_level[:40] if isinstance(file_level, str) else short_repr(file_level)
        raise AudioError(
            f"threshold file {path} holds a threshold of the {shown_level} level, not of the"
            f" {level} level: calibrate again with --bit-source {level}"
        )
    value = record["threshold_db"]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise AudioError(f"threshold file {path}: threshold_db must be a number,"
                         f" got {short_repr(value)}")
    if not finite(value):
        raise AudioError(f"threshold file {path}: threshold_db must be finite,"
                         f" got {short_repr(value)}")
    return check_threshold_db(value, f"threshold file {path}")
