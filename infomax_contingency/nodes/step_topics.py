"""The stamped step-clock topics: bits and decisions with their step identity.

``sound`` and ``vocalize`` (std_msgs/Bool) carry the values people echo and the speaker
obeys; beside them travel, on common interfaces only (std_msgs/Int64MultiArray, one
dimension labelled with the field names):

* ``sound_step``: ``[stream, step, bit, window_us]`` — the bit ``y_t`` of window
  ``step`` (1, 2, ...) of ``stream`` (a random id chosen by each run of mic_node), whose
  windows last ``window_us`` microseconds;
* ``vocalize_step``: ``[stream, step, vocalize, controller]`` — the decision ``u_t`` on
  that window, by ``controller`` (a random id chosen by each run of controller_node);
* ``step_applied``: ``[stream, step, listener]`` — ``listener`` (a random id chosen by
  each run of belief_node) applied every step of ``stream`` up to ``step``: mic_node's
  flow control waits for it (:class:`~infomax_contingency.core.flowcontrol.StepOutbox`).

A listener joins the two exactly by ``(stream, step)``
(:class:`~infomax_contingency.core.stepclock.StepJoiner`) and follows one stream and one
controller (:class:`~infomax_contingency.core.stepclock.SourceLock`).
"""

from __future__ import annotations

import secrets
from typing import NamedTuple

from std_msgs.msg import Int64MultiArray, MultiArrayDimension

SOUND_STEP = "sound_step"
VOCALIZE_STEP = "vocalize_step"
STEP_APPLIED = "step_applied"

_SOUND_FIELDS = ("stream", "step", "bit", "window_us")
_VOCALIZE_FIELDS = ("stream", "step", "vocalize", "controller")
_APPLIED_FIELDS = ("stream", "step", "listener")


class StepBit(NamedTuple):
    """A bit with its identity."""

    stream: int
    step: int
    bit: bool
    window_us: int


class StepApplied(NamedTuple):
    """A listener's acknowledgment: it applied every step of ``stream`` up to ``step``."""

    stream: int
    step: int
    listener: int


class StepDecision(NamedTuple):
    """A decision with the identity of the bit it answers."""

    stream: int
    step: int
    vocalize: bool
    controller: int


def new_source_id() -> int:
    """A random positive id for a stream or a controller (48 bits: exact in JSON/YAML)."""
    return secrets.randbits(48) + 1


def _dimension(fields: tuple[str, ...]) -> MultiArrayDimension:
    return MultiArrayDimension(label=",".join(fields), size=len(fields), stride=len(fields))


_LAYOUTS = {fields: [_dimension(fields)]
            for fields in (_SOUND_FIELDS, _VOCALIZE_FIELDS, _APPLIED_FIELDS)}
"""The one-dimension layout of each message kind, made once (a message per window)."""


def _message(fields: tuple[str, ...], values: tuple[int, ...]) -> Int64MultiArray:
    message = Int64MultiArray()
    message.layout.dim = _LAYOUTS[fields]
    message.data = [int(v) for v in values]
    return message


def bit_message(bit: StepBit) -> Int64MultiArray:
    """The ``sound_step`` message of ``bit``."""
    return _message(_SOUND_FIELDS, tuple(bit))


def decision_message(decision: StepDecision) -> Int64MultiArray:
    """The ``vocalize_step`` message of ``decision``."""
    return _message(_VOCALIZE_FIELDS, tuple(decision))


def applied_message(applied: StepApplied) -> Int64MultiArray:
    """The ``step_applied`` message of ``applied``."""
    return _message(_APPLIED_FIELDS, tuple(applied))


def parse_applied(message: Int64MultiArray) -> StepApplied | None:
    """The acknowledgment in a ``step_applied`` message, or None if it is malformed."""
    data = list(message.data)
    if len(data) != len(_APPLIED_FIELDS) or min(data) <= 0:
        return None
    return StepApplied(*data)


def _fields(message: Int64MultiArray, n: int) -> list[int] | None:
    data = list(message.data)
    if len(data) != n or data[0] <= 0 or data[1] <= 0 or data[2] not in (0, 1):
        return None
    return data


def parse_bit(message: Int64MultiArray) -> StepBit | None:
    """The bit in a ``sound_step`` message, or None if the message is malformed."""
    data = _fields(message, len(_SOUND_FIELDS))
    if data is None or data[3] <= 0:
        return None
    return StepBit(data[0], data[1], bool(data[2]), data[3])


def parse_decision(message: Int64MultiArray) -> StepDecision | None:
    """The decision in a ``vocalize_step`` message, or None if the message is malformed."""
    data = _fields(message, len(_VOCALIZE_FIELDS))
    if data is None or data[3] <= 0:
        return None
    return StepDecision(data[0], data[1], bool(data[2]), data[3])


def window_us(window_s: float) -> int:
    """A window length in whole microseconds (how ``sound_step`` carries it)."""
    return round(window_s * 1e6)
