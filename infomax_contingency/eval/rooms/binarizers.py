"""Binarizers by name: the grammar ``SOURCE[:MODE][:ARGUMENT...]`` over the bit-source registry."""

from __future__ import annotations

import math
from typing import Any

from infomax_contingency.audio.bitsources import BIT_SOURCES, BitSource, make_bit_source
from infomax_contingency.audio.bitsources.base import NameArgument, SettingSpec
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.core.model import ModelParams

SHORT_NAME_SOURCE = "energy"
"""The source of a name that starts with a threshold mode (``calibrate``, ``fixed:-40``)."""


def _placeholders(arguments: tuple[NameArgument, ...]) -> str:
    """``:DB`` / ``[:S]`` / ``[:MARGIN_DB[:WARMUP_S]]`` of a mode's arguments."""
    required = "".join(f":{a.placeholder}" for a in arguments if a.required)
    optional = [a.placeholder for a in arguments if not a.required]
    return required + ("[:" + "[:".join(optional) + "]" * len(optional) if optional else "")


def _grammar() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(the binarizer names of every registered source, the sources that share ``SOURCE``)."""
    shared = [n for n, s in BIT_SOURCES.items() if s.mode_setting is not None
              and s.name_modes == BIT_SOURCES[SHORT_NAME_SOURCE].name_modes]  # fmt: skip
    short = BIT_SOURCES[SHORT_NAME_SOURCE].name_modes
    names = [f"{mode}{_placeholders(args)}" for mode, args in short.items()]
    names += [f"SOURCE:{mode}{_placeholders(args)}" for mode, args in short.items()]
    for name, source in BIT_SOURCES.items():
        if name not in shared:
            names += [f"{name}{':' + mode if mode else ''}{_placeholders(args)}"
                      for mode, args in source.name_modes.items()]  # fmt: skip
    return tuple(names), tuple(shared)


BINARIZERS, LEVEL_SOURCES = _grammar()
"""Binarizer names (the grammar of :func:`binarizer_options`), made from the bit sources'
declarations (:data:`~infomax_contingency.audio.bitsources.BIT_SOURCES`: each source's
``name_modes`` and settings), and the sources that are ``SOURCE`` in them:

* ``SOURCE`` is ``energy`` (the window energy, the paper's rule) or ``speech_band`` (the
  300-3400 Hz band's energy); without it (``calibrate``, ``fixed:-40``, ...) the source is
  ``energy``, so the older names keep their meaning.
* ``calibrate[:S]``: k-means on the first S seconds (default 10; ``threshold_mode
  calibrate``, ``calibration_s``); ``fixed:DB``: a fixed threshold, dB (``threshold_db``);
  ``noise_floor[:MARGIN_DB[:WARMUP_S]]``: MARGIN_DB (default 10, ``noise_margin_db``)
  above the tracked floor, which starts on the first WARMUP_S seconds (default 10,
  ``calibration_s``); ``file:PATH``: a threshold file of the source's level;
  ``background[:FALSE_ALARM[:MARGIN_DB[:HISTORY_S]]]``: the self-calibrating threshold at
  a share FALSE_ALARM (default 0.05, ``false_alarm``) of the model's background windows
  of the last HISTORY_S seconds (default 30, ``background_window_s``), plus MARGIN_DB
  (default 0, ``background_margin_db``).
* ``vad[:AGGRESSIVENESS[:MIN_VOICED_S]]``: WebRTC's voice-activity detector,
  aggressiveness 0-3 (default 2) and the voiced time a window needs, s (default 0.1).

A new source's names come with its registration.
"""


class BinarizerNameError(ValueError):
    """A binarizer name outside the grammar of :data:`BINARIZERS` (one line, lists it)."""

    def __init__(self, spec: str, reason: str) -> None:
        super().__init__(
            f"binarizer {spec!r}: {reason}; binarizers: {', '.join(BINARIZERS)}"
            f" (SOURCE: {' or '.join(LEVEL_SOURCES)})"
        )


def _value(spec: str, text: str, argument: NameArgument, declared: SettingSpec) -> Any:
    """The setting an argument's text gives, in its declared type and range."""
    value: Any = text
    if isinstance(declared.default, int):
        try:
            value = int(text)
        except ValueError:
            raise BinarizerNameError(spec, f"bad whole number {text!r} for"
                                     f" {argument.placeholder}") from None  # fmt: skip
    elif isinstance(declared.default, float):
        try:
            value = float(text)
        except ValueError:
            raise BinarizerNameError(
                spec, f"bad number {text!r} for {argument.placeholder}"
            ) from None
        if not math.isfinite(value):
            raise BinarizerNameError(spec, f"{argument.placeholder} must be finite, got {text!r}")
    try:
        return declared.check(value)
    except AudioError as error:
        raise BinarizerNameError(spec, f"{argument.placeholder}: {error}") from None


def _source_and_words(spec: str) -> tuple[str, list[str]]:
    """The source a name stands for and the words after it (a short name is energy's)."""
    words = spec.split(":")
    if words[0] in BIT_SOURCES:
        return words[0], words[1:]
    if words[0] not in BIT_SOURCES[SHORT_NAME_SOURCE].name_modes:
        raise BinarizerNameError(spec, "unknown binarizer")
    return SHORT_NAME_SOURCE, words


def _mode_and_words(spec: str, name: str, words: list[str]) -> tuple[str, list[str]]:
    """The mode word of a source that has modes ("" for one without) and the arguments."""
    source = BIT_SOURCES[name]
    if source.mode_setting is None:
        return "", words
    if not words or not words[0]:
        raise BinarizerNameError(spec, f"{name} needs a {source.mode_setting}, e.g."
                                 f" {name}:{next(iter(source.name_modes))}")  # fmt: skip
    if words[0] not in source.name_modes:
        raise BinarizerNameError(spec, f"unknown {source.mode_setting} {words[0]!r}")
    return words[0], words[1:]


def binarizer_options(spec: str) -> tuple[str, dict[str, Any]]:
    """The bit source and the :func:`make_bit_source` options a binarizer name stands for.

    The name is ``SOURCE[:MODE][:ARGUMENT...]`` as the source declares it
    (:attr:`~infomax_contingency.audio.bitsources.base.BitSource.name_modes`); a name that
    starts with a mode of :data:`SHORT_NAME_SOURCE` is that source's.

    Raises:
        BinarizerNameError: the name is outside the grammar of :data:`BINARIZERS`.
    """
    name, words = _source_and_words(spec)
    mode, words = _mode_and_words(spec, name, words)
    source = BIT_SOURCES[name]
    options: dict[str, Any] = {source.mode_setting: mode} if source.mode_setting else {}
    arguments = source.name_modes[mode]
    declared = {s.name: s for s in source.specs()}
    last = len(arguments) - 1
    final = declared[arguments[-1].setting] if arguments else None
    free_text = final is not None and isinstance(final.default, str) and final.choices is None
    if 0 <= last < len(words) - 1 and free_text:
        words = [*words[:last], ":".join(words[last:])]  # a path may hold ':'
    if len(words) > len(arguments):
        takes = " and ".join(a.placeholder for a in arguments) or "no argument"
        raise BinarizerNameError(spec, f"{name}{':' + mode if mode else ''} takes at most {takes}")
    for argument, text in zip(arguments, words + [""] * len(arguments), strict=False):
        if text:
            options[argument.setting] = _value(spec, text, argument, declared[argument.setting])
        elif argument.required:
            raise BinarizerNameError(spec, f"{mode or name} needs {argument.placeholder}:"
                                     f" {mode or name}:{argument.placeholder}")  # fmt: skip
    return name, options


def make_binarizer(
    spec: str,
    window_s: float,
    rate_hz: int = PROCESSING_RATE_HZ,
    params: ModelParams | None = None,
) -> BitSource:
    """A fresh bit source from its name (:data:`BINARIZERS`) for windows of ``window_s`` s.

    ``params``: the model whose periods label the windows of a source that
    :attr:`~infomax_contingency.audio.bitsources.base.BitSource.needs_decisions`
    (``background``; default: the robot's).

    One implementation: the name is parsed by :func:`binarizer_options` and the source
    made by :func:`~infomax_contingency.audio.bitsources.make_bit_source`, as mic_node makes
    it from its parameters. A bad name or value: ValueError, one line with the grammar.
    """
    source, options = binarizer_options(spec)
    try:
        bits = make_bit_source(source, rate_hz, window_s, **options)
    except AudioError as error:
        raise BinarizerNameError(spec, str(error)) from None
    if params is not None and bits.needs_decisions:
        bits.follow_model(params)
    return bits
