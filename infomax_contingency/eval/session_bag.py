"""A recorded session's steps as belief_node took them, read from its bag (no rclpy).

:func:`load_session` reads the first mic stream of a recorder_node bag with the live
nodes' rules (malformed messages skipped, forged jumps ahead left out) and what the bag
says of how to replay it: the windows' length, belief_node's memory and resets (from the
diagnostics of the session's own namespace), steps recorded twice or out of order (a
second writer) and a restarted mic_node. :mod:`infomax_contingency.eval.sessions`
replays it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S
from infomax_contingency.core.model import NAMED_PARAMS, ModelParams, Withheld
from infomax_contingency.core.stepclock import Pace, StepPace
from infomax_contingency.core.stepfields import (
    StepBit,
    StepDecision,
    bit_of,
    decision_of,
    valid_messages,
    window_us,
)

StepT = TypeVar("StepT", StepBit, StepDecision)

SESSION_TOPICS = ("/sound_step", "/vocalize_step", "/belief", "/diagnostics")
"""Topics a replay with recorded actions reads."""


@dataclass
class RecordedSession:
    """The steps of one recorded mic stream.

    Attributes:
        bits: ``(step, bit)`` of the first stream heard, in arrival order.
        decisions: ``(step, vocalize)`` for that stream, in arrival order.
        beliefs: the recorded ``belief`` values, in arrival order.
        memory_steps: belief_node's memory (from its diagnostics; 0 = whole history).
        memory_problem: why the diagnostics do not tell belief_node's memory ("": they
            do, or hold none of any belief_node: the whole history).
        doubtful: ``(step, what)`` of the steps whose bit or decision was recorded twice
            or out of order (a second writer: the live nodes tell it by its DDS numbers,
            which a bag does not hold), in arrival order.
        resets: how often belief_node's ``~/reset`` was called (its diagnostics' count).
        belief_restarts: ``(joined, last)`` per new belief_node (another ``listener_id``
            in its diagnostics: a restarted node): the step it joined the stream at with
            zero counts, and the last step the one before it reported applied.
        restart: ``(stream, step)``: a later stream the controller answered too (a
            restarted mic_node), first heard after ``step`` of this one; None if none.
        later_streams: ``(stream, bits, decisions)`` of each later stream the controller
            answered, in that order, from the first step it answered (belief_node follows
            them so, its counts kept).
        cut: the bag was cut by a killed recorder (read up to its last chunk).
        window_us: the length of the stream's windows (its steps), microseconds.
        stream: the stream's id (mic_node's, random per start).
        k2_per_lag: the model belief_node's beliefs were of (one K2 per agent timer value
            or one K2, from its diagnostics); None: they do not say (recorded before they
            did, or by no belief_node of this namespace, or two that differ).
    """

    bits: list[tuple[int, bool | Withheld]]
    decisions: list[tuple[int, bool]]
    beliefs: list[float]
    memory_steps: int
    cut: bool = False
    window_us: int = 0
    memory_problem: str = ""
    doubtful: list[tuple[int, str]] = field(default_factory=list)
    restart: tuple[int, int] | None = None
    resets: int = 0
    belief_restarts: list[tuple[int, int]] = field(default_factory=list)
    stream: int = 0
    later_streams: list[tuple[int, list[tuple[int, bool | Withheld]], list[tuple[int, bool]]]] = (
        field(default_factory=list))
    k2_per_lag: bool | None = None


def load_session(directory: Path, warn: Callable[[str], None] | None = None
                 ) -> RecordedSession:
    """Read the steps of the first mic stream of a session bag.

    ``warn`` is told of a bag cut by a killed recorder (read up to its last chunk), of
    an MCAP file its metadata.yaml does not list (another recording added: not read), of
    malformed step messages (skipped, as the live nodes ignore them: one line per topic)
    and of forged jumps ahead (left out).

    Raises:
        BagReadError: the bag cannot be read, is damaged, or is not a session (no
            ``sound_step`` and ``vocalize_step``, or topics of other types).
        ValueError: it holds no valid ``sound_step`` message (nothing to replay).
    """
    # Imported here: sessions need the optional rosbags; the other commands start without it.
    from infomax_contingency.audio.bag import read_topics, unlisted_recordings

    cut: list[str] = []

    def warn_cut(message: str) -> None:
        cut.append(message)
        if warn is not None:
            warn(message)

    topics = read_topics(directory, SESSION_TOPICS,
                         required=("/sound_step", "/vocalize_step"), warn=warn_cut)
    for name in unlisted_recordings(directory) if warn is not None else ():
        warn(f"the session {directory} also holds {name}, which its metadata.yaml does not"
             " list: not read (another recording? give each its own directory)")
    bit_messages = valid_messages(((t, m.data) for t, m in topics["/sound_step"]), bit_of,
                                  "/sound_step", warn)
    if not bit_messages:
        raise ValueError(f"the session {directory} holds no valid sound_step messages: nothing"
                         " to replay (was mic_node running while it was recorded?)")
    first = bit_messages[0][1]
    stream, rate_hz = first.stream, 1e6 / first.window_us
    bits = [(bit.step, bit.observation)
            for bit in _on_pace(bit_messages, stream, rate_hz, "bit", warn)]
    decision_messages = valid_messages(((t, m.data) for t, m in topics["/vocalize_step"]),
                                       decision_of, "/vocalize_step", warn)
    decisions = [(d.step, d.vocalize)
                 for d in _on_pace(decision_messages, stream, rate_hz, "decision", warn)]
    beliefs = [float(m.data) for _, m in topics["/belief"]]
    memory, problem = _belief_memory(topics["/diagnostics"], topics.namespace)
    doubtful = sorted(_out_of_sequence([step for step, _ in bits], "bit")
                      + _out_of_sequence([step for step, _ in decisions], "decision"))
    return RecordedSession(bits, decisions, beliefs, memory, cut=bool(cut),
                           window_us=first.window_us, memory_problem=problem, stream=stream,
                           doubtful=doubtful, restart=_restart(bit_messages, decision_messages),
                           resets=max((v for v in _own_values(topics["/diagnostics"],
                                                              topics.namespace, "resets")[1]
                                       if isinstance(v, int)), default=0),  # fmt: skip
                           belief_restarts=_belief_restarts(topics["/diagnostics"],
                                                            topics.namespace),
                           later_streams=_later_streams(bit_messages, decision_messages,
                                                        rate_hz, warn),
                           k2_per_lag=_belief_model(topics["/diagnostics"], topics.namespace))


def _later_streams(bits: list[tuple[int, StepBit]], decisions: list[tuple[int, StepDecision]],
                   rate_hz: float, warn: Callable[[str], None] | None
                   ) -> list[tuple[int, list[tuple[int, bool | Withheld]], list[tuple[int, bool]]]]:
    """The streams answered after the first, as belief_node takes them (``later_streams``).

    belief_node follows the stream the controller answers from the first step answered
    (older bits were never answered); each stream's messages on pace, as the first's.
    """
    first = bits[0][1].stream
    answered = list(dict.fromkeys(d.stream for _, d in decisions if d.stream != first))
    streams = []
    for stream in answered:
        taken = _on_pace(decisions, stream, rate_hz, "decision", warn)
        if not taken:
            continue
        start = min(d.step for d in taken)
        stream_bits = [(b.step, b.observation)
                       for b in _on_pace(bits, stream, rate_hz, "bit", warn) if b.step >= start]
        streams.append((stream, stream_bits, [(d.step, d.vocalize) for d in taken]))
    return streams


def _restart(bits: list[tuple[int, StepBit]], decisions: list[tuple[int, StepDecision]]
             ) -> tuple[int, int] | None:
    """``(stream, step)``: the first later stream that decisions answer, after that step.

    A stream the controller answers besides the first is a restarted mic_node's (a
    second microphone's bits are not answered); ``step``: the first stream's newest step
    when the new stream's first bit was recorded.
    """
    answered = {decision.stream for _, decision in decisions}
    first, newest = bits[0][1].stream, 0
    for _, bit in bits:
        if bit.stream == first:
            newest = max(newest, bit.step)
        elif bit.stream in answered:
            return bit.stream, newest
    return None


def _out_of_sequence(steps: list[int], what: str) -> list[tuple[int, str]]:
    """``(step, what happened)`` of the steps recorded twice or out of order.

    One source publishes each step once, in order: a step that repeats or goes back
    (``steps`` in arrival order) was published by a second writer too.
    """
    found: list[tuple[int, str]] = []
    seen: set[int] = set()
    newest = 0
    for step in steps:
        if step in seen:
            found.append((step, f"the {what} of step {step} recorded twice"))
        elif step < newest:
            found.append((step, f"the {what} of step {step} recorded out of order (after"
                                f" step {newest})"))
        seen.add(step)
        newest = max(newest, step)
    return found


def check_window(session: RecordedSession, params: ModelParams, params_name: str,
                 directory: object) -> None:
    """Refuse ``params`` whose dt (s) is not the session's window length.

    A step of the session is one of its windows; the model's periods count windows of
    ``params.dt``: other windows would give other periods and times, and belief_node
    itself ignores bits of windows other than its dt.

    Raises:
        ValueError: one line naming both lengths and the parameters to give.
    """
    if session.window_us == window_us(params.dt):
        return
    window_s = session.window_us / 1e6
    named = [name for name, p in NAMED_PARAMS.items() if window_us(p.dt) == session.window_us]
    which = f" ({', '.join(named)})" if named else ""
    raise ValueError(f"the session {directory} has windows of {window_s:g} s; the parameter"
                     f" set {params_name} (--params) has windows of {params.dt:g} s: give"
                     f" --params with dt {window_s:g}{which}")


def check_belief_model(session: RecordedSession, params: ModelParams, params_name: str,
                       directory: object) -> None:
    """Refuse ``params`` whose ``k2_per_lag`` is not the one the session's beliefs were of.

    A session that does not say (recorded before belief_node reported it) passes.

    Raises:
        ValueError: one line naming both and the parameters to give.
    """
    recorded = session.k2_per_lag
    if recorded is not None and recorded != params.k2_per_lag:
        raise ValueError(f"the session {directory}'s belief_node had {belief_model(recorded)}"
                         f" (k2_per_lag {str(recorded).lower()}); the parameter set"
                         f" {params_name} (--params) has {belief_model(params.k2_per_lag)}:"
                         f" give --params with k2_per_lag: {str(recorded).lower()}")


def belief_model(k2_per_lag: bool) -> str:
    """The belief model of ``k2_per_lag``, in words."""
    return "one K2 per agent timer value" if k2_per_lag else "one K2"


def check_same_windows(sessions: Sequence[tuple[object, RecordedSession]]) -> None:
    """Refuse sessions (``(name, session)``) whose windows differ: their lags are not pooled.

    Raises:
        ValueError: one line naming a session of each length (seconds).
    """
    lengths = {session.window_us: name for name, session in reversed(sessions)}
    if len(lengths) > 1:
        named = ", ".join(f"{name}: {us / 1e6:g} s" for us, name in sorted(lengths.items()))
        raise ValueError(f"the sessions have windows of different lengths ({named}): a lag"
                         " counts windows, so analyze sessions of one window length together")


def _on_pace(messages: list[tuple[int, StepT]], stream: int, rate_hz: float, what: str,
             warn: Callable[[str], None] | None) -> list[StepT]:
    """The step messages of ``stream`` the live nodes take: a forged jump ahead is left out.

    The same rule as belief_node's and controller_node's
    (:class:`~infomax_contingency.core.stepclock.StepPace`, confirmed after
    ``SOURCE_TIMEOUT_S``), on the times the recorder received them (``messages``:
    ``(ns, parsed message)``). ``warn`` is told of each message left out.
    """
    pace = StepPace(rate_hz, SOURCE_TIMEOUT_S)
    taken: list[StepT] = []
    for received_ns, data in messages:
        if data.stream != stream:
            continue
        verdict = pace.check(data.step, received_ns / 1e9, data)
        if verdict is Pace.ON_PACE:
            taken.append(data)
        elif verdict is Pace.CONFIRMED:
            taken.extend(pace.take_confirmed())
        elif warn is not None:
            warn(pace.jump_message(f"the recorded {what} for step {data.step}"))
    return taken


def _belief_memory(diagnostics: list, namespace: str) -> tuple[int, str]:
    """The session's belief_node's ``memory_steps``, and why it is not known ("" if it is).

    The session's own node is the belief_node of its ``namespace`` (``/robot1``:
    ``robot1/belief_node``, as its diagnostics name it): ``/diagnostics`` holds those of
    every robot on the domain. None of any belief_node: 0 (the whole history).
    """
    own, values = _own_values(diagnostics, namespace, "memory_steps")
    reported = _belief_node_values(diagnostics, "memory_steps")
    if len(values) == 1 and isinstance(values[0], int):
        return values[0], ""
    if any(isinstance(value, str) for value in values):
        return 0, (f"the diagnostics of {own} report memory_steps"
                   f" {' and '.join(map(str, values))}, not one whole number of steps (0 or"
                   " more, at most 18 digits): its memory cannot be told")
    if len(values) > 1:
        return 0, (f"the diagnostics of {own} report memory_steps"
                   f" {' and '.join(map(str, values))} (two belief_nodes of one name on the"
                   " domain?): its memory cannot be told")
    if reported:
        return 0, (f"the diagnostics hold no memory_steps of this session's {own}, only of"
                   f" {', '.join(sorted(reported))}: its memory cannot be told")
    return 0, ""


def _belief_model(diagnostics: list, namespace: str) -> bool | None:
    """The ``k2_per_lag`` the session's belief_node reported (None: none, or both)."""
    own = f"{namespace.strip('/')}/belief_node".lstrip("/")
    said = {pair.value for _, array in diagnostics for status in array.status
            if status.name.split(":", 1)[0] == own
            for pair in status.values if pair.key == "k2_per_lag"}  # fmt: skip
    return {"True": True, "False": False}.get(said.pop()) if len(said) == 1 else None


def _belief_node_values(diagnostics: list, key: str) -> dict[str, set[int | str]]:
    """``node -> values of key`` that every belief_node (of any namespace) reported.

    A value that is not a whole number >= 0 (another robot's, a forged one) is kept as
    its text, cut to 40 characters, for the one who reads it to name.
    """
    reported: dict[str, set[int | str]] = {}
    for _, array in diagnostics:
        for status in array.status:
            node = status.name.split(":", 1)[0]  # robot1/belief_node: P(S=1) = ...
            for pair in status.values:
                if pair.key == key and node.rsplit("/", 1)[-1] == "belief_node":
                    text = str(pair.value)
                    whole = text.isascii() and text.isdigit() and len(text) <= 18
                    reported.setdefault(node, set()).add(int(text) if whole else text[:40])
    return reported


def _belief_restarts(diagnostics: list, namespace: str) -> list[tuple[int, int]]:
    """``(joined, last)`` per new instance of the session's belief_node (a restart).

    ``joined``: the step it joined its stream at; ``last``: the last step the instance
    before it reported applied. Each instance reports its random ``listener_id``; a new
    one's first report gives the step it joined at (``last_step - steps + 1``: it applied
    ``steps`` steps since).
    """
    own = f"{namespace.strip('/')}/belief_node".lstrip("/")
    restarts: list[tuple[int, int]] = []
    listener, last = None, 0
    for _, array in diagnostics:
        for status in array.status:
            if status.name.split(":", 1)[0] != own:
                continue
            values = {pair.key: pair.value for pair in status.values}
            try:
                current, newest = int(values["listener_id"]), int(values["last_step"])
                steps = int(values["steps"])
            except (KeyError, ValueError):
                continue
            joined = newest - steps + 1
            if steps < 1 or joined < 1:  # not joined a stream yet (or forged): no step known
                continue
            if listener is not None and current != listener:
                restarts.append((joined, last))
            listener, last = current, newest
    return restarts


def _own_values(diagnostics: list, namespace: str, key: str) -> tuple[str, list[int | str]]:
    """The session's belief_node (of ``namespace``) and the values of ``key`` it reported.

    Whole numbers first, then the texts of any that are not.
    """
    own = f"{namespace.strip('/')}/belief_node".lstrip("/")
    values = _belief_node_values(diagnostics, key).get(own, set())
    return own, sorted(v for v in values if isinstance(v, int)) + sorted(
        repr(v) for v in values if isinstance(v, str))


def session_memory(session: RecordedSession, memory: int | None) -> int:
    """The memory a replay keeps (steps): ``memory`` if given, else belief_node's.

    Raises:
        ValueError: not given, and the session's diagnostics do not tell it (one line).
    """
    if memory is not None:
        return memory
    if session.memory_problem:
        raise ValueError(f"{session.memory_problem}: give --memory N")
    return session.memory_steps
