"""Does a recorded session's replay equal the beliefs belief_node published, and why not.

The verdict of ``replay BAG`` (:mod:`infomax_contingency.cli.sessions`): the replay
(:func:`~infomax_contingency.eval.sessions.replay_recorded`) compared step for step with
the recorded beliefs, with what the bag says happened named: belief_node's resets (located
where the recorded beliefs show them), restarted belief_nodes (each replayed from its
join), a recorder that joined late or was cut, a second writer of a step. Pure: no rclpy,
no printing.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import islice

from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.sessions import (
    RecordedSession,
    belief_model,
    replay_recorded,
    with_session_model,
)
from infomax_contingency.sim.simulation import StepRecord


def replay_with_its_model(session: RecordedSession, params: ModelParams, memory: int | None
                           ) -> tuple[ModelParams, list[StepRecord], bool, str]:
    """The replay with ``params`` or the session's other belief model, and its verdict.

    The model: :func:`~infomax_contingency.eval.sessions.with_session_model`. Returns the
    parameters replayed with, the records, whether they equal, the verdict.
    """
    def replay(model: ModelParams) -> tuple[bool, tuple[list[StepRecord], bool, str]]:
        records, resets = _replay_locating_resets(session, model, memory)
        same, verdict = belief_verdict(session, [(r.t, r.belief) for r in records], resets)
        return same, (records, same, verdict)

    chosen, (records, same, verdict), told = with_session_model(session, params, replay)
    if told:
        verdict += (f", with {belief_model(chosen.k2_per_lag)} (k2_per_lag"
                    f" {str(chosen.k2_per_lag).lower()}: the session does not say its belief"
                    " model, and its beliefs are that one's)")
    return chosen, records, same, verdict


MOST_RESETS_LOCATED = 20
"""belief_node resets a replay locates (one replay of the session each); beyond, the rest
are named as not located and the comparison stops at the first difference."""
MOST_RESTARTS_COMPARED = 100
"""belief_node restarts whose beliefs a replay compares; beyond (a node crashing in a loop,
forged diagnostics) only the first node's are (the split's work grows with their square)."""


def restarted_belief_nodes(session: RecordedSession, params: ModelParams, memory: int | None,
                           records: list[StepRecord], verdict: str) -> tuple[bool, str]:
    """The verdict with each restarted belief_node's own beliefs compared too.

    The one that joined at step ``join`` started with zero counts (replayed so:
    ``from_step``); the one before it published the beliefs of its steps up to some step
    K, from the last step it reported to the step before the join. The recorded beliefs
    are each one's in turn: a split of them at such K's where every one's agree with its
    replay (none: a later one's beliefs differ).
    """
    restarts = session.belief_restarts
    if len(restarts) > MOST_RESTARTS_COMPARED:  # not shown equal: exit status 1
        return False, (f"{verdict.removesuffix(')')}; belief_node restarted {len(restarts)}"
                       f" times, more than the {MOST_RESTARTS_COMPARED} whose beliefs the replay"
                       " splits: the later ones' not compared)")  # fmt: skip
    firsts = [1] + [join for join, _ in restarts]
    ends = [max(later - first, 0) for first, later in zip(firsts[1:], firsts[2:], strict=False)]
    replays = [[r.belief for r in records]] + [  # each up to the next one's join at most
        [r.belief for r in islice(replay_recorded(session, params, memory, from_step=join), end)]
        for join, end in zip(firsts[1:], [*ends, None], strict=True)]  # fmt: skip
    published = _split_beliefs(session.beliefs, replays, firsts, [last for _, last in restarts])
    if published is None:
        joins = ", ".join(str(join) for join in firsts[1:])
        steps = "steps" if len(restarts) > 1 else "step"
        return False, (f"replayed belief DIFFERS from the recorded one after the belief_node"
                       f" restart: no split of the {len(session.beliefs)} recorded beliefs gives"
                       f" the first one's and those of a new one from {steps} {joins} with zero"
                       " counts")  # fmt: skip
    parts = [f"the new one's {count} beliefs, replayed from step {join} with zero counts (the"
             f" one before published {before})"
             for count, join, before in zip(published[1:], firsts[1:], published[:-1], strict=True)]
    return True, (f"{verdict.removesuffix(')')}; and {'; '.join(parts)}; {sum(published)}"
                  " recorded beliefs compared in all)")


def _split_beliefs(recorded: list[float], replays: list[list[float]], firsts: list[int],
                   lasts: list[int]) -> list[int] | None:
    """How many of ``recorded`` each belief_node published in turn, or None if no split fits.

    Node ``i`` published the beliefs of steps ``firsts[i]`` on, the first of its
    ``replays[i]``; every node but the last at least up to the step it reported last
    (``lasts[i]``) and at most up to the step before the next one joined; the last one
    the rest, no more than its replay holds. Node by node, the offsets into ``recorded``
    where the next one can begin (each reached once, with the count that reached it): no
    recursion, and work that grows with the square of the nodes at most.
    """
    reached: list[dict[int, int]] = [{0: 0}]  # per node: offset it begins at -> count before
    for node, own in enumerate(replays[:-1]):
        least = max(lasts[node] - firsts[node] + 1, 0)
        most = firsts[node + 1] - firsts[node]
        following: dict[int, int] = {}
        for offset in reached[node]:
            agree = 0  # the node's first beliefs equal to the recorded ones from offset
            limit = min(most, len(own), len(recorded) - offset)
            while agree < limit and recorded[offset + agree] == own[agree]:
                agree += 1
            for count in range(least, agree + 1):
                following.setdefault(offset + count, count)
        if not following:
            return None
        reached.append(following)
    own = replays[-1]
    ends = [offset for offset in reached[-1] if len(recorded) - offset <= len(own)
            and recorded[offset:] == own[:len(recorded) - offset]]  # fmt: skip
    if not ends:
        return None
    counts, offset = [len(recorded) - ends[0]], ends[0]
    for node in range(len(replays) - 1, 0, -1):
        counts.insert(0, reached[node][offset])
        offset -= counts[0]
    return counts


def _replay_locating_resets(session: RecordedSession, params: ModelParams,
                            memory: int | None) -> tuple[list[StepRecord], list[int]]:
    """The replayed steps, with belief_node's resets where the recorded beliefs show them.

    A reset (``~/reset``, counted in the diagnostics) falls between two steps: the first
    step whose recorded belief differs is taken as the one after it when the replay with
    the history forgotten there agrees further on. Returns the steps and the resets
    located (indices of the steps after them, from 0).
    """
    resets: list[int] = []
    records = list(replay_recorded(session, params, memory))
    while len(resets) < min(session.resets, MOST_RESETS_LOCATED):
        at = _first_difference(session, records)
        if at is None:
            break
        trial = list(replay_recorded(session, params, memory, [*resets, at]))
        later = _first_difference(session, trial)
        if later is not None and later <= at:
            break
        resets.append(at)
        records = trial
    return records, resets


def _first_difference(session: RecordedSession, records: list[StepRecord]) -> int | None:
    """The index of the first replayed step whose belief differs from the recorded one."""
    recorded, _ = _aligned_beliefs(session, [(r.t, r.belief) for r in records])
    if recorded is None:
        return None
    return next((i for i, (r, b) in enumerate(zip(records, recorded, strict=False))
                 if r.belief != b), None)


def _aligned_beliefs(session: RecordedSession, replayed: list[tuple[int, float]]
                     ) -> tuple[list[float] | None, list[str]]:
    """The recorded belief of each replayed step (None: they cannot be matched), and notes.

    Beliefs carry no step: a bag whose first bit is step ``s > 1`` of its stream (the
    recorder joined late) is matched when its beliefs are those of the last steps, from
    step ``s`` or earlier (the recorder heard belief_node before mic_node).
    """
    beliefs, count = session.beliefs, len(replayed)
    first = min(step for step, _ in session.bits)
    if first == 1 and session.belief_restarts:
        join, last = session.belief_restarts[0]  # the first one's beliefs: steps 1 .. last
        kept = min(last, len(beliefs))
        return beliefs[:kept], [f"belief_node restarted (a new one joined at step {join} with"
                                f" zero counts, the one before reported step {last} last, its"
                                f" diagnostics say): compared the first one's {kept}"
                                " beliefs"]
    if first == 1:
        if session.cut and count > len(beliefs):  # the cut took the last beliefs
            return beliefs, [f"the last {count - len(beliefs)} replayed steps have no"
                             " recorded belief (cut): compared up to the last one recorded"]
        if count > len(beliefs):
            return beliefs, [f"{count - len(beliefs)} replayed steps have no recorded belief"
                             " (the recorder missed belief_node's first beliefs or its last):"
                             f" compared the first {len(beliefs)}, from step 1"]
        return beliefs, []
    late = (f"the recorder joined late: the bag's first bit is step {first} of its stream"
            f" (steps 1-{first - 1} not recorded: the replay starts without their history)")
    offset = replayed[-1][0] - len(beliefs) if replayed else -1  # beliefs: steps offset+1..
    if session.cut or not 0 <= offset <= first - 1:
        return None, [f"{late}; its {len(beliefs)} recorded beliefs cannot be matched to the"
                      f" {count} replayed steps"]
    matched = [beliefs[step - 1 - offset] for step, _ in replayed]
    skipped = f", after the {first - 1 - offset} beliefs of the steps not recorded" if (
        first - 1 > offset) else ""
    return matched, [f"{late}; compared from step {first}{skipped}"]


def belief_verdict(session: RecordedSession, replayed: list[tuple[int, float]],
                   resets: Sequence[int] = ()) -> tuple[bool, str]:
    """Do the replayed ``(step, belief)`` equal the recorded beliefs, and the verdict line.

    True only when at least one step was compared and every one compared is equal.
    ``resets``: the indices of the steps before which belief_node's resets were applied.
    """
    recorded, notes = _aligned_beliefs(session, replayed)
    if session.resets:
        located = ", ".join(str(replayed[i][0]) for i in resets)
        notes.append(f"belief_node was reset during the session (diagnostics: resets"
                     f" {session.resets})" + (f": replayed with the history forgotten before"
                                              f" step(s) {located}, where the recorded"
                                              " belief shows it" if located else ""))
    values = [belief for _, belief in replayed]
    counts = f"{len(values)} steps replayed, {len(session.beliefs)} beliefs recorded"
    if not values or not session.beliefs:
        what = "no step was replayed" if not values else "no belief was recorded"
        return False, f"nothing was compared: {what} ({counts})"
    if recorded is None:
        return False, f"nothing was compared ({counts}; {'; '.join(notes)})"
    compared = min(len(values), len(recorded))
    if not compared and not session.belief_restarts:  # restarted: the split compares them
        return False, f"nothing was compared ({counts}; {'; '.join(notes)})"
    first_difference = next((i for i in range(compared) if values[i] != recorded[i]), None)
    extra = len(recorded) - len(values)
    if session.restart is not None:
        stream, step = session.restart
        notes.append(f"mic_node restarted (stream {stream} after step {step}): replayed"
                     " across it as belief_node follows it (counts kept, the timer forgotten)")
    if extra > 0:
        notes.append(f"{extra} more beliefs than steps were recorded: a second publisher on"
                     " /belief (a forged message?) or a restarted belief_node")
    detail = "".join(f"; {note}" for note in notes)
    if first_difference is None and extra <= 0:
        return True, (f"replayed belief equals the recorded belief at all {compared} steps"
                      f" compared ({counts}{detail})")
    if first_difference is None:
        where, equal = f"after step {replayed[-1][0]}: more beliefs were recorded", compared
    else:
        where, equal = f"at step {replayed[first_difference][0]}", first_difference
        if len(resets) < session.resets:
            detail += (f"; {session.resets - len(resets)} reset(s) not located: compared up"
                       f" to step {replayed[first_difference][0]}")
        detail += "".join(f"; {note}" for note in
                          _second_writer(session, replayed[first_difference][0]))
    return False, (f"replayed belief DIFFERS from the recorded one {where} ({counts},"
                   f" {compared} compared, the first {equal} equal{detail})")


def _second_writer(session: RecordedSession, step: int) -> list[str]:
    """The note on steps recorded twice or out of order up to ``step`` (none: [])."""
    doubtful = [what for at, what in session.doubtful if at <= step]
    if not doubtful:
        return []
    return [f"{', '.join(doubtful)}: a second writer (forged?); the live nodes ignored its"
            " messages by their DDS numbers, which the bag does not hold: the replay"
            " cannot tell which was the true one"]
