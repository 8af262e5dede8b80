"""The stamped step-clock topics: bits and decisions with their step identity.

``sound`` and ``vocalize`` (std_msgs/Bool) carry the values people echo and the speaker
obeys; beside them travel, on common interfaces only (std_msgs/Int64MultiArray, one
dimension labelled with the field names):

* ``sound_step``: ``[stream, step, bit, window_us, withheld]`` — the bit ``y_t`` of
  window ``step`` (1, 2, ...) of ``stream`` (a random id chosen by each run of mic_node),
  whose windows last ``window_us`` microseconds; ``withheld`` is 1 when the window
  overlapped sound the robot declared as its own (``self_sound``) or came right after
  windows without a step (:class:`~infomax_contingency.core.selfsound.GapWithholding`):
  the bit is what was heard, but it is no evidence and no listener counts it
  (:class:`~infomax_contingency.core.model.Withheld`). A message of the first four
  fields only (recordings made before ``withheld`` existed) is a window not withheld;
* ``vocalize_step``: ``[stream, step, vocalize, controller]`` — the decision ``u_t`` on
  that window, by ``controller`` (a random id chosen by each run of controller_node);
* ``step_applied``: ``[stream, step, listener]`` — ``listener`` (a random id chosen by
  each run of belief_node) applied every step of ``stream`` up to ``step``: mic_node's
  flow control waits for it (:class:`~infomax_contingency.core.flowcontrol.StepOutbox`);
* ``no_step``: ``[stream, window]`` — mic_node heard window ``window`` (1, 2, ... of all
  the windows it made, stepped or not) of ``stream`` and it yields no step: its bit
  source is calibrating or warming up. A lockstep room (fake_audio_node) releases its
  next window on it, as it does on the decision on a window that gave a step.

A listener joins the two exactly by ``(stream, step)``
(:class:`~infomax_contingency.core.stepclock.StepJoiner`) and follows one stream and one
controller (:class:`~infomax_contingency.core.stepclock.SourceLock`).
"""

from __future__ import annotations

import secrets
from typing import NamedTuple

from std_msgs.msg import Int64MultiArray, MultiArrayDimension

from infomax_contingency.core.stepfields import SOUND_FIELDS as _SOUND_FIELDS
from infomax_contingency.core.stepfields import VOCALIZE_FIELDS as _VOCALIZE_FIELDS
from infomax_contingency.core.stepfields import (
    StepBit,
    StepDecision,
    bit_of,
    decision_of,
    window_us,  # noqa: F401 - the nodes take it from here
)

SOUND_STEP = "sound_step"
VOCALIZE_STEP = "vocalize_step"
STEP_APPLIED = "step_applied"
NO_STEP = "no_step"
SELF_SOUND = "self_sound"
"""The topic on which any node declares the robot's own sound (see
:mod:`~infomax_contingency.core.selfsound`)."""

_SELF_SOUND_FIELDS = ("start_ns", "end_ns")
_APPLIED_FIELDS = ("stream", "step", "listener")
_NO_STEP_FIELDS = ("stream", "window")


class StepApplied(NamedTuple):
    """A listener's acknowledgment: it applied every step of ``stream`` up to ``step``."""

    stream: int
    step: int
    listener: int


class NoStep(NamedTuple):
    """Window ``window`` of ``stream`` (counting every window mic_node made) gave no step."""

    stream: int
    window: int


def new_source_id() -> int:
    """A random positive id for a stream or a controller (48 bits: exact in JSON/YAML)."""
    return secrets.randbits(48) + 1


def _dimension(fields: tuple[str, ...]) -> MultiArrayDimension:
    return MultiArrayDimension(label=",".join(fields), size=len(fields), stride=len(fields))


_LAYOUTS = {
    fields: [_dimension(fields)]
    for fields in (_SOUND_FIELDS, _VOCALIZE_FIELDS, _SELF_SOUND_FIELDS, _APPLIED_FIELDS,
                   _NO_STEP_FIELDS)
}
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


def no_step_message(no_step: NoStep) -> Int64MultiArray:
    """The ``no_step`` message of ``no_step``."""
    return _message(_NO_STEP_FIELDS, tuple(no_step))


def parse_no_step(message: Int64MultiArray) -> NoStep | None:
    """The window in a ``no_step`` message, or None if the message is malformed."""
    data = list(message.data)
    if len(data) != len(_NO_STEP_FIELDS) or min(data) <= 0:
        return None
    return NoStep(*data)


def parse_applied(message: Int64MultiArray) -> StepApplied | None:
    """The acknowledgment in a ``step_applied`` message, or None if it is malformed."""
    data = list(message.data)
    if len(data) != len(_APPLIED_FIELDS) or min(data) <= 0:
        return None
    return StepApplied(*data)


def parse_bit(message: Int64MultiArray) -> StepBit | None:
    """The bit in a ``sound_step`` message, or None if the message is malformed.

    Four fields (a recording made before ``withheld``) are a window not withheld
    (the rules: :func:`~infomax_contingency.core.stepfields.bit_of`).
    """
    return bit_of(message.data)


def self_sound_message(start_ns: int, end_ns: int) -> Int64MultiArray:
    """The ``self_sound`` message declaring the robot's sound over ``[start_ns, end_ns]``.

    Times are nanoseconds on the ROS clock (``node.get_clock().now().nanoseconds``).
    """
    return _message(_SELF_SOUND_FIELDS, (start_ns, end_ns))


def parse_self_sound(message: Int64MultiArray) -> tuple[int, int] | None:
    """``(start_ns, end_ns)`` of a ``self_sound`` message; None if it has not two fields."""
    data = list(message.data)
    return (int(data[0]), int(data[1])) if len(data) == 2 else None


def parse_decision(message: Int64MultiArray) -> StepDecision | None:
    """The decision in a ``vocalize_step`` message, or None if the message is malformed."""
    return decision_of(message.data)
