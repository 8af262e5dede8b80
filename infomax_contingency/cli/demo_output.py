"""The demo's output: the table of its steps and its verdict, from what the monitor recorded.

``recorder`` is the demo's :class:`~infomax_contingency.testing.graph.StepRecorder`: per
step the bit (``sound``), the decision (``vocalize``), the belief and the posture changes
received, and per window the simulated room's truth (``partner_present``).
"""

from __future__ import annotations

import argparse
from typing import Any

from infomax_contingency.core.posture import ATTENTIVE_ABOVE, BORED, BORED_BELOW, PostureHysteresis


def step_postures(beliefs: list[float], received: list[str]) -> list[str]:
    """The posture after each step.

    The posture node publishes a change in answer to the belief that crossed a
    threshold; the same hysteresis on the recorded beliefs says which step that was. If
    the changes it finds are not the ones the node published (other thresholds in a
    parameter file), the node's changes are shown at the steps the monitor received them.
    """
    hysteresis = PostureHysteresis(ATTENTIVE_ABOVE, BORED_BELOW, received[0] if received else BORED)
    per_step = []
    for belief in beliefs:
        hysteresis.update(belief)
        per_step.append(hysteresis.posture)
    changes = [p for i, p in enumerate(per_step) if i == 0 or p != per_step[i - 1]]
    return per_step if changes[1:] == received[1:] else []


def print_run(recorder: Any, steps: int, window_s: float, truth: bool) -> None:
    """Print one line per step: its window's time (s), bit, decision, belief and posture.

    ``truth``: also whether the simulated room's partner was there.
    """
    windows = recorder.step_windows(steps)
    if windows and windows[0] > 0:
        print(f"# the first {windows[0]} windows ({windows[0] * window_s:g} s) gave no bit:"
              " mic_node's bit source heard the room's background first")  # fmt: skip
    beliefs = recorder.belief[:steps]
    received = [posture for _, posture in recorder.posture]
    postures = step_postures(beliefs, received)
    if not postures:  # fall back to the arrival order
        postures, current, changes = [], received[0] if received else "?", list(recorder.posture)
        for step in range(1, steps + 1):
            while changes and changes[0][0] <= step:
                current = changes.pop(0)[1]
            postures.append(current)
    header = f"{'step':>5} {'time_s':>7} {'bit':>3} {'vocalize':>8} {'belief':>9}  {'posture':<9}"
    print((header + (" partner" if truth else "")).rstrip())
    for k in range(steps):
        line = (
            f"{k + 1:>5} {windows[k] * window_s:>7.1f} {int(recorder.sound[k]):>3}"
            f" {'yes' if recorder.vocalize[k] else '-':>8} {beliefs[k]:>9.4f}  {postures[k]:<9}"
        )
        if truth:
            line += " present" if recorder.partner_present[windows[k]] else " absent"
        print(line.rstrip())


def print_verdict(
    recorder: Any, steps: int, window_s: float, args: argparse.Namespace, elapsed: float
) -> None:
    """Print the run's figures and whether the robot found the partner and ended right.

    ``elapsed``: s from the first node's start to the last step.
    """
    beliefs = recorder.belief[:steps]
    final = beliefs[-1]
    thinks = "partner present" if final > 0.5 else "no partner"
    received = [t for t, _ in recorder.times["belief"][:steps]]
    run_s = (received[-1] - received[0]) / 1e9 if len(received) > 1 else 0.0
    rate = f" ({(steps - 1) / run_s:.0f} steps/s)" if run_s > 0 else ""
    audio_s = (steps + len(recorder.no_step)) * window_s
    print(
        f"# {steps} steps ({audio_s:g} s of audio) in {run_s:.2f} s{rate}, after"
        f" {elapsed - run_s:.1f} s of start-up; {sum(recorder.vocalize[:steps])} vocalizations;"
        f" final P(S=1) = {final:.4f} -> {thinks}"
    )
    if args.wav:
        print(f"# verdict: the robot thinks: {thinks} (a recording has no ground truth)")
        return
    windows = recorder.step_windows(steps)  # of each step; the truth is the window's
    truth = recorder.partner_present[: windows[-1] + 1]
    present = [w for w, here in enumerate(truth) if here]
    verdicts = []
    if present:
        arrive, leave = present[0], present[-1] + 1  # windows
        found = next((k for k in range(steps)
                      if arrive <= windows[k] < leave and beliefs[k] > ATTENTIVE_ABOVE), None)
        if found is None:
            verdicts.append("MISSED the partner")
        else:
            delay = (windows[found] - arrive + 1) * window_s
            verdicts.append(
                f"found the partner {delay:.1f} s after they arrived (step {found + 1})"
            )
        if leave < len(truth):
            gone = next((k for k in range(steps)
                         if windows[k] >= leave and beliefs[k] < BORED_BELOW), None)
            if gone is None:
                verdicts.append("did NOT notice that the partner left")
            else:
                delay = (windows[gone] - leave + 1) * window_s
                verdicts.append(f"noticed they left {delay:.1f} s later (step {gone + 1})")
    else:
        ok = max(beliefs) <= ATTENTIVE_ABOVE
        verdicts.append(
            "never took the room for a partner" if ok else "WRONGLY took the room for a partner"
        )
    right = (final > 0.5) == bool(truth[-1])
    verdicts.append(f"final answer {'correct' if right else 'WRONG'}")
    print("# verdict: " + "; ".join(verdicts))


def complete_steps(recorder: Any) -> int:
    """Steps whose bit, decision and belief the monitor has all received."""
    return min(len(recorder.sound), len(recorder.vocalize), len(recorder.belief))


def print_run_so_far(recorder: Any, window_s: float, truth: bool) -> None:
    """The table of the steps complete when the demo was interrupted (nothing if none).

    With ``truth``, only the steps whose window's truth has come too (it may lag).
    """
    steps = 0 if recorder is None else complete_steps(recorder)
    if steps and truth:
        known = len(recorder.partner_present)
        steps = sum(1 for window in recorder.step_windows(steps) if window < known)
    if steps:
        print_run(recorder, steps, window_s, truth)
        print(f"# interrupted after {steps} steps", flush=True)
