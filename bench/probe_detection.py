"""Six probes behind docs/RESULTS.md section 7's "what was tried": detection figures, printed.

``levels``: an observation richer than one bit. Each window of the default runs gets one
of three levels, referenced to the room's background windows like the default bit
source: 2 = the default bit is active; 1 = not, but the window is louder than all but a
share ``--share`` of the background windows known ``ta2 + 1`` windows before it (the
k-th loudest, k as the default source takes it); 0 = neither. The belief is the model's
with Dirichlet priors in place of its Beta priors (the same exact posterior, for three
outcomes): uniform (1, 1, 1) on the agent period's levels, and on the background's the
shares the thresholds set, worth 10 windows (as the robot set's Beta(0.5, 9.5) is for
one bit). The decisions are those of the default runs (the controller keeps its table on
the bits); the figures compare the posture's settling on the same runs.

``timer``: the share of active bits by timer value (0 .. ta2 + 1) in empty rooms, with the
robot's chirp as the room plays it and with it muted (no sound, no echo): windows after
a vocalization are compared with the background windows the model takes as their
reference; ``--controller`` puts another controller in the optimal table's place (one
that ignores the bits: ``random:0.125``, ``fixed:8``).

``table``: how one more active bit, of the background or of the agent period, changes the
optimal table's decision at the background timer value, over statistics sampled as in an
empty room.

``decisions``: the background windows the robot decided to vocalize on, against all
background windows (active share, median level), and the agent windows' active share;
``--controller`` as for ``timer``.

``context``: a belief for windows that are not independent. Each counted window's context
is the bit of the counted window before it (0 for the first); the bits are a Markov chain:
under S = 0 every counted window is active with probability ``K3[c]`` in context ``c``,
under S = 1 the agent period's with ``K2[c]`` and the background's with ``K3[c]``, each
with its own Beta prior (the model's for context 0; for context 1 the agent's and
``--context-prior`` for the background). The exact posterior, recomputed on the default
runs like ``levels``; ``average`` is the Bayesian average (even odds) of this model and
the model's independent windows. With ``--gated``, on the runs of the ``gate`` probe's table.

``gate``: the optimal table, but a vocalization it decides on an active window is put off
to the next quiet one (the robot never asks while the room is loud); the bit source and
the belief are the default's.

Run from the repository root::

    .venv/bin/python bench/probe_detection.py levels [--rooms tv-on+partner,...] [--runs 100]
        [--no-reference]
    .venv/bin/python bench/probe_detection.py timer [--rooms street,...] [--runs 100]
        [--controller random:0.125]
    .venv/bin/python bench/probe_detection.py table
    .venv/bin/python bench/probe_detection.py decisions [--rooms street,tv-on+partner]
        [--controller fixed:8]
    .venv/bin/python bench/probe_detection.py context [--rooms ...] [--runs 100]
        [--context-prior 1,1] [--gated]
    .venv/bin/python bench/probe_detection.py gate [--rooms ...] [--runs 100]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
from collections.abc import Iterator

import numpy as np
from scipy.special import gammaln

from infomax_contingency.audio.background import BackgroundThreshold
from infomax_contingency.audio.bitsources.background import LEAST_RANK
from infomax_contingency.audio.common import AudioError
from infomax_contingency.core.controllers import Controller, PolicyController
from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    ModelParams,
    Statistic,
    Withheld,
    belief_from_log_odds,
    betaln,
    period_of,
)
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.eval.rooms import controller_specs, run_room
from infomax_contingency.eval.rooms import running as rooms_running
from infomax_contingency.eval.rooms.config import RoomsConfig
from infomax_contingency.eval.rooms.running import RoomRun
from infomax_contingency.eval.rooms.scoring import postures, settled_step
from infomax_contingency.sim.fake_room import FakeRoomConfig

HISTORY_WINDOWS = 60
"""Background windows a level's threshold is taken over (the default source's 30 s)."""
BELIEF_MEMORY = RoomsConfig().memory
"""The belief's sliding memory, steps, as in ``experiment rooms``."""
WARMUP_WINDOWS = 8
"""Background windows known before a window can be given level 1."""
REFERENCE_MARGIN_DB = 3.0
"""The default source's ``reference_margin_db``."""
BACKGROUND_PRIOR_WINDOWS = 10.0
"""What the Dirichlet prior on the background's levels is worth, windows."""


def log_dirichlet(alpha: np.ndarray) -> float:
    """Log of the multivariate Beta function of ``alpha``."""
    return float(np.sum(gammaln(alpha)) - gammaln(np.sum(alpha)))


def dirichlet_log_odds(
    params: ModelParams, agent: np.ndarray, background: np.ndarray,
    agent_prior: np.ndarray, background_prior: np.ndarray,
) -> float:  # fmt: skip
    """Log posterior odds of S = 1 from level counts (MODEL.md section 2 with Dirichlets)."""
    prior = math.log(params.pi) - math.log1p(-params.pi)
    return (
        prior
        + log_dirichlet(agent_prior + agent)
        - log_dirichlet(agent_prior)
        + log_dirichlet(background_prior + background)
        - log_dirichlet(background_prior + agent + background)
    )


def levels_of(params: ModelParams, run: RoomRun, share: float, reference: bool) -> np.ndarray:
    """Level 0, 1 or 2 of each step of ``run`` (the module's docstring).

    Level 1 is the default source's own rule (:class:`BackgroundThreshold`) at the false-alarm
    share ``share``, fed the run's windows and decisions; with ``reference`` it keeps the
    source's reference rule (louder than the window the robot's last sound followed, by
    :data:`REFERENCE_MARGIN_DB`), without it not.
    """
    rule = BackgroundThreshold(
        params.ts1, params.ts2, params.ta2, false_alarm=share, history=HISTORY_WINDOWS,
        warmup_windows=WARMUP_WINDOWS, ta1=params.ta1, reference=reference,
        reference_margin_db=REFERENCE_MARGIN_DB, least_rank=LEAST_RANK,
    )  # fmt: skip
    levels = np.where(run.y == 1, 2, 0)
    for t, (level, decision) in enumerate(zip(run.energy_db, run.u, strict=True)):
        louder = rule.push(float(level), decision=int(decision))
        if not run.y[t] and louder:
            levels[t] = 1
    return levels


def belief_log_odds(
    params: ModelParams, run: RoomRun, observations: np.ndarray, outcomes: int,
    agent_prior: np.ndarray, background_prior: np.ndarray, memory: int,
) -> np.ndarray:  # fmt: skip
    """Log odds after each step: the counts of the last ``memory`` counted observations."""
    periods = period_of(params, run.z)
    counted: list[tuple[int, int]] = []
    out = np.zeros(observations.size)
    for t, (period, observation) in enumerate(zip(periods, observations, strict=True)):
        if period in (AGENT, BACKGROUND):
            counted = [*counted, (int(period), int(observation))][-memory:]
        counts = {AGENT: np.zeros(outcomes), BACKGROUND: np.zeros(outcomes)}
        for counted_period, counted_observation in counted:
            counts[counted_period][counted_observation] += 1
        out[t] = dirichlet_log_odds(
            params, counts[AGENT], counts[BACKGROUND], agent_prior, background_prior
        )
    return out


def outcome(run: RoomRun, log_odds: np.ndarray, partner_room: bool) -> int | bool | None:
    """Vocalizations to a settled posture (partner room; None: never), or ever attentive."""
    beliefs = belief_from_log_odds(log_odds)
    attentive = postures(beliefs, 0.9, 0.2)
    if not partner_room:
        return bool(attentive.any())
    settled = settled_step(attentive, run.partner, beliefs, 0.2, 0)
    return None if settled is None else int(run.u[:settled].sum())


def probe_levels(
    params: ModelParams, rooms: list[str], runs: int, shares: list[float], reference: bool
) -> None:
    """Print the ``levels`` probe (the module's docstring)."""
    spec = controller_specs(params, ["optimal"])[0][1]
    false_alarm = 0.05
    for room in rooms:
        partner_room = room.endswith("+partner")
        results: dict[str, list] = {"one bit": []} | {f"3 levels, share {s:g}": [] for s in shares}
        for k in range(runs):
            run = run_room(params, room, spec, "background", 60.0, 0, k, BELIEF_MEMORY)
            bit_log_odds = belief_log_odds(
                params, run, run.y.astype(int), 2, np.array([params.b22, params.b21]),
                np.array([params.b32, params.b31]), BELIEF_MEMORY,
            )  # fmt: skip
            if not np.allclose(bit_log_odds, run.log_odds):
                raise SystemExit("the Dirichlet belief on one bit differs from the model's")
            results["one bit"].append(outcome(run, run.log_odds, partner_room))
            for share in shares:
                shares_set = np.array([1 - share, share - false_alarm, false_alarm])
                log_odds = belief_log_odds(
                    params, run, levels_of(params, run, share, reference), 3, np.ones(3),
                    BACKGROUND_PRIOR_WINDOWS * shares_set, BELIEF_MEMORY,
                )  # fmt: skip
                results[f"3 levels, share {share:g}"].append(outcome(run, log_odds, partner_room))
        for name, values in results.items():
            print_outcomes(room, name, values, runs)


def probe_timer(params: ModelParams, rooms: list[str], runs: int, controller: str) -> None:
    """Print the ``timer`` probe (the module's docstring) with ``controller`` deciding."""
    spec = controller_specs(params, ["optimal"])[0][1] if controller == "optimal" else controller
    preset = FakeRoomConfig.preset
    timers = range(params.ta2 + 2)
    for room in rooms:
        for muted in (False, True):

            def room_config(name: str, muted: bool = muted) -> FakeRoomConfig:
                config = preset(name)
                if muted:
                    config = dataclasses.replace(config, self_level_db=-150.0, reverb_rt60_s=0.0)
                return config

            active: dict[int, list[int]] = {z: [] for z in timers}
            FakeRoomConfig.preset = staticmethod(room_config)  # type: ignore[method-assign]
            try:
                for k in range(runs):
                    run = run_room(params, room, spec, "background", 60.0, 0, k, BELIEF_MEMORY)
                    for z in timers:
                        active[z].extend(run.y[run.z == z].tolist())
            finally:
                FakeRoomConfig.preset = staticmethod(preset)  # type: ignore[method-assign]
            cells = "  ".join(f"z={z}: {np.mean(active[z]):.3f}" for z in timers)
            print(f"{room:<14} {'chirp muted' if muted else 'as played':<12} {cells}")


def log_beta_bernoulli(prior: tuple[float, float], active: float, quiet: float) -> float:
    """Log marginal likelihood of a bit sequence with these counts under a Beta prior."""
    a, b = prior
    return float(betaln(a + active, b + quiet) - betaln(a, b))


def context_log_odds(
    params: ModelParams, run: RoomRun, contexts: np.ndarray,
    background_active_prior: tuple[float, float], average: bool,
) -> np.ndarray:  # fmt: skip
    """Log odds of S = 1 after each step under the ``context`` probe's Markov model.

    ``contexts``: each step's context (0/1); the last :data:`BELIEF_MEMORY` counted windows
    count, as for the belief node. With ``average`` the odds are those of the Bayesian
    average (even prior odds) of this model and the model's independent windows.
    """
    agent_prior = (params.b21, params.b22)
    background_priors = ((params.b31, params.b32), background_active_prior)
    periods = period_of(params, run.z)
    counted: list[tuple[int, int, int]] = []
    prior_odds = math.log(params.pi) - math.log1p(-params.pi)
    out = np.zeros(run.y.size)
    for t, period in enumerate(periods):
        if period in (AGENT, BACKGROUND):
            counted = [*counted, (0 if period == AGENT else 1, int(contexts[t]), int(run.y[t]))]
            counted = counted[-BELIEF_MEMORY:]
        n = np.zeros((2, 2, 2))  # [agent 0 / background 1, context, bit]
        for which, context, bit in counted:
            n[which, context, bit] += 1
        markov_partner = sum(
            log_beta_bernoulli(agent_prior, n[0, c, 1], n[0, c, 0])
            + log_beta_bernoulli(background_priors[c], n[1, c, 1], n[1, c, 0])
            for c in (0, 1)
        )
        markov_none = sum(
            log_beta_bernoulli(
                background_priors[c], n[0, c, 1] + n[1, c, 1], n[0, c, 0] + n[1, c, 0]
            )
            for c in (0, 1)
        )
        if not average:
            out[t] = prior_odds + markov_partner - markov_none
            continue
        agent, background = n[0].sum(axis=0), n[1].sum(axis=0)
        independent_partner = log_beta_bernoulli(
            agent_prior, agent[1], agent[0]
        ) + log_beta_bernoulli(background_priors[0], background[1], background[0])
        independent_none = log_beta_bernoulli(
            background_priors[0], agent[1] + background[1], agent[0] + background[0]
        )
        out[t] = (
            prior_odds
            + np.logaddexp(independent_partner, markov_partner)
            - np.logaddexp(independent_none, markov_none)
        )
    return out


def previous_counted_bits(params: ModelParams, run: RoomRun) -> np.ndarray:
    """Each step's context: the bit of the counted window before it (0 for the first)."""
    periods = period_of(params, run.z)
    contexts = np.zeros(run.y.size, dtype=int)
    last = 0
    for t, period in enumerate(periods):
        contexts[t] = last
        if period in (AGENT, BACKGROUND):
            last = int(run.y[t])
    return contexts


def print_outcomes(room: str, name: str, values: list, runs: int) -> None:
    """One line: settled share and median vocalizations, or the share ever attentive."""
    if room.endswith("+partner"):
        settled = [v for v in values if v is not None]
        median = np.median([math.inf if v is None else v for v in values])
        print(f"{room:<24} {name:<30} settled {len(settled)}/{runs}, median"
              f" vocalizations {median:g} (a run never settled counts as inf)")  # fmt: skip
    else:
        print(f"{room:<24} {name:<30} ever attentive {sum(values)}/{runs}")


def probe_context(
    params: ModelParams,
    rooms: list[str],
    runs: int,
    background_active_prior: tuple[float, float],
    gated: bool,
) -> None:
    """Print the ``context`` probe (the module's docstring); ``gated``: the gated table decides."""
    spec = controller_specs(params, ["optimal"])[0][1]
    variants = {"Markov": False, "average with independent": True}
    for room in rooms:
        partner_room = room.endswith("+partner")
        results: dict[str, list] = {"independent (the default)": []} | {v: [] for v in variants}
        cells = np.zeros((2, 2, 2))  # [agent 0 / background 1, context, bit] over the runs
        for k in range(runs):
            with gated_tables() if gated else contextlib.nullcontext():
                run = run_room(params, room, spec, "background", 60.0, 0, k, BELIEF_MEMORY)
            no_context = context_log_odds(
                params, run, np.zeros(run.y.size, dtype=int), background_active_prior, False
            )
            if not np.allclose(no_context, run.log_odds):
                raise SystemExit("the Markov belief in one context differs from the model's")
            results["independent (the default)"].append(outcome(run, run.log_odds, partner_room))
            contexts = previous_counted_bits(params, run)
            periods = period_of(params, run.z)
            for which, period in enumerate((AGENT, BACKGROUND)):
                for context in (0, 1):
                    bits = run.y[(periods == period) & (contexts == context)]
                    cells[which, context] += (np.sum(bits == 0), np.sum(bits == 1))
            for name, average in variants.items():
                odds = context_log_odds(params, run, contexts, background_active_prior, average)
                results[name].append(outcome(run, odds, partner_room))
        shares = "; ".join(
            f"{period} after {'an active' if context else 'a quiet'} window"
            f" {cells[which, context, 1] / max(cells[which, context].sum(), 1):.3f}"
            f" ({cells[which, context].sum() / runs:.1f} per run)"
            for which, period in enumerate(("agent", "background"))
            for context in (0, 1)
        )
        print(f"{room:<24} active share: {shares}")
        for name, values in results.items():
            print_outcomes(room, name, values, runs)


class QuietGatedController(PolicyController):
    """The optimal table, but a vocalization decided on an active window is put off."""

    window_active = False

    def step(self, y: int | Withheld) -> int:
        """As :meth:`PolicyController.step`, with u = 0 whenever the window's bit is 1."""
        self.window_active = y == 1
        return super().step(y)

    def decide(self, statistic: Statistic) -> int:
        """The table's decision, or silence on an active window."""
        return 0 if self.window_active else super().decide(statistic)


@contextlib.contextmanager
def gated_tables() -> Iterator[None]:
    """Within the block, the rooms experiment's table controllers are quiet-gated."""
    make = rooms_running.experiment_controller

    def gated(spec: str, params: ModelParams, rng: np.random.Generator) -> Controller:
        controller = make(spec, params, rng)
        if isinstance(controller, PolicyController):
            return QuietGatedController(controller.table)
        return controller

    rooms_running.experiment_controller = gated  # type: ignore[assignment]
    try:
        yield
    finally:
        rooms_running.experiment_controller = make  # type: ignore[assignment]


def probe_gate(params: ModelParams, rooms: list[str], runs: int) -> None:
    """Print the ``gate`` probe (the module's docstring)."""
    spec = controller_specs(params, ["optimal"])[0][1]
    for room in rooms:
        partner_room = room.endswith("+partner")
        names = ("the table (the default)", "the table, quiet-gated")
        results: dict[str, list] = {name: [] for name in names}
        bits: dict[str, dict[int, list]] = {name: {AGENT: [], BACKGROUND: []} for name in names}
        for k in range(runs):
            for name in names:
                with gated_tables() if name.endswith("gated") else contextlib.nullcontext():
                    run = run_room(params, room, spec, "background", 60.0, 0, k, BELIEF_MEMORY)
                if name.endswith("gated") and np.any(run.u[run.y == 1]):
                    raise SystemExit("the gated table vocalized on an active window")
                results[name].append(outcome(run, run.log_odds, partner_room))
                periods = period_of(params, run.z)
                for period in (AGENT, BACKGROUND):
                    bits[name][period].extend(run.y[periods == period].tolist())
        for name, values in results.items():
            print_outcomes(room, name, values, runs)
            print(f"{room:<24} {name:<30} active share: agent {np.mean(bits[name][AGENT]):.3f},"
                  f" background {np.mean(bits[name][BACKGROUND]):.3f}")  # fmt: skip


LEVELS_ROOMS = "tv-on+partner,living-room+partner,open-office+partner,street,home-office"
"""Rooms of the ``levels`` probe by default: where the default misses a target."""
CONTEXT_ROOMS = (
    "quiet+partner,office+partner,open-office+partner,tv-on+partner,living-room+partner,"
    "street+partner,home-office+partner,street,home-office,crowd-grows,tv-switched-on"
)
"""Rooms of the ``context`` and ``gate`` probes: the missed targets and the fast rooms."""


def probe_decisions(params: ModelParams, rooms: list[str], runs: int, controller: str) -> None:
    """Print the ``decisions`` probe: the windows the robot decided to ask on, against the rest.

    Per room: the share of active bits and the median level (dB) of the background windows
    on which the controller decided to vocalize, and of all background windows; and the
    share of active agent-period bits after those decisions.
    """
    spec = controller_specs(params, ["optimal"])[0][1] if controller == "optimal" else controller
    for room in rooms:
        decided: list[tuple[int, float]] = []
        background: list[tuple[int, float]] = []
        agent: list[int] = []
        for k in range(runs):
            run = run_room(params, room, spec, "background", 60.0, 0, k, BELIEF_MEMORY)
            periods = period_of(params, run.z)
            for t in range(run.y.size):
                if periods[t] == BACKGROUND:
                    window = (int(run.y[t]), float(run.energy_db[t]))
                    background.append(window)
                    if run.u[t]:
                        decided.append(window)
            agent.extend(run.y[periods == AGENT].tolist())
        cells = []
        for name, windows in (("decided on", decided), ("all background", background)):
            bits, levels = zip(*windows, strict=True) if windows else ((), ())
            cells.append(f"{name}: {np.mean(bits):.3f} active, median {np.median(levels):.1f} dB"
                         f" ({len(windows)})")  # fmt: skip
        print(f"{room:<16} {controller[:12]:<12} " + "; ".join(cells)
              + f"; agent windows {np.mean(agent):.3f} active")  # fmt: skip


def probe_table(params: ModelParams, samples: int) -> None:
    """Print the ``table`` probe: how one more active bit changes the table's decision.

    Statistics sampled as in an empty room's sliding memory (``n2 + n3 <= 60``, bits active
    with probability 0.05), at the background timer value ``z = ta2 + 1`` (where the
    timer stays until the robot vocalizes).
    """
    table = PolicyTable.load(controller_specs(params, ["optimal"])[0][1].removeprefix("policy:"))
    rng = np.random.default_rng(1)
    z = params.ta2 + 1
    asks = {"background": [0, 0], "agent": [0, 0]}  # [asks where it would not, stays silent]
    for _ in range(samples):
        n2 = int(rng.integers(1, 25))
        n3 = int(rng.integers(1, 61 - n2))
        p2, p3 = int(rng.binomial(n2 - 1, 0.05)), int(rng.binomial(n3 - 1, 0.05))
        before = table.action(Statistic(z, p2, n2 - p2, p3, n3 - p3))
        for period, after in (
            ("background", table.action(Statistic(z, p2, n2 - p2, p3 + 1, n3 - p3 - 1))),
            ("agent", table.action(Statistic(z, p2 + 1, n2 - p2 - 1, p3, n3 - p3))),
        ):
            asks[period][0] += after > before
            asks[period][1] += after < before
    for period, (more, fewer) in asks.items():
        print(f"one more active {period} bit: asks where it would not have in {more / samples:.1%},"
              f" stays silent where it would have asked in {fewer / samples:.1%}"
              f" of {samples} statistics")  # fmt: skip


def main() -> None:
    """Parse the command line and print the chosen probe."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "probe", choices=("levels", "timer", "table", "decisions", "context", "gate")
    )
    parser.add_argument("--rooms", default="")
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--shares", default="0.25,0.5", help="levels: shares for level 1")
    parser.add_argument(
        "--controller",
        default="optimal",
        help="timer: optimal (the default table) or a controller specification, e.g. random:0.125",
    )
    parser.add_argument(
        "--no-reference",
        action="store_true",
        help="levels: level 1 without the reference to an earlier window",
    )
    parser.add_argument(
        "--context-prior",
        default="1,1",
        help="context: the Beta prior (a,b) on the background's rate after an active window",
    )
    parser.add_argument(
        "--gated", action="store_true", help="context: on the runs of the gate probe's table"
    )
    args = parser.parse_args()
    if args.runs < 1:
        parser.error(f"--runs must be at least 1, got {args.runs}")
    try:
        run_probe(args)
    except (ValueError, AudioError) as error:  # a bad room, share or controller: one line
        parser.error(str(error))


def run_probe(args: argparse.Namespace) -> None:
    """Run the probe ``args`` name (ValueError or AudioError for a bad room, share, controller)."""
    params = ModelParams.named("robot")
    if args.probe == "levels":
        rooms = args.rooms or LEVELS_ROOMS
        shares = [float(s) for s in args.shares.split(",")]
        if not all(0.05 < share <= 0.5 for share in shares):
            raise ValueError(f"--shares must lie in (0.05, 0.5] (above the bit's), got {shares}")
        probe_levels(params, rooms.split(","), args.runs, shares, not args.no_reference)
    elif args.probe in ("context", "gate"):
        rooms = (args.rooms or CONTEXT_ROOMS).split(",")
        if args.probe == "gate":
            probe_gate(params, rooms, args.runs)
            return
        try:
            prior = tuple(float(v) for v in args.context_prior.split(","))
        except ValueError:
            prior = ()
        if len(prior) != 2 or not all(v > 0 for v in prior):
            raise ValueError(f"--context-prior must be two numbers > 0, got {args.context_prior}")
        probe_context(params, rooms, args.runs, (prior[0], prior[1]), args.gated)
    elif args.probe == "table":
        probe_table(params, 20000)
    elif args.probe == "decisions":
        rooms = args.rooms or "street,tv-on+partner"
        probe_decisions(params, rooms.split(","), args.runs, args.controller)
    else:
        rooms = args.rooms or "street,home-office,crowd-grows,office"
        probe_timer(params, rooms.split(","), args.runs, args.controller)


if __name__ == "__main__":
    main()
