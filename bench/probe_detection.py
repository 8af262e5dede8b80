"""Nine probes behind docs/RESULTS.md section 7's "what was tried": detection figures, printed.

Every run here is the table alone (``run_room`` without controller_node's check-ins), as
when these probes were measured; ``straddle`` goes through ``experiment rooms`` and so has
the check-ins unless given ``--check-in-every-s 0``.

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
With ``--persistence``, also with the prior on the background's rate after an active window
estimated, step by step, from the room's background levels as the bit source could:
``exceedance`` (loud windows at ``--persistence-share``, their odds ratio carried to the bits'
rate) or ``copula`` (the rank correlation of consecutive levels through Gaussian levels); each
prior has the estimate's mean and variance. Each room's line "any counted window after an active
one" is the rate such an estimate aims at (in an empty room: what ``--context-prior`` is given
for the belief told the room's persistence exactly).

``gate``: the optimal table, but a vocalization it decides on an active window is put off
to the next quiet one (the robot never asks while the room is loud); the bit source and
the belief are the default's.

``straddle``: the default bit source, but a window's level is the louder of its own and that
of the 0.5 s straddling it and the window before (a reply that crosses a window edge is heard
whole in one of them); every window alike, so the threshold still sets the false-alarm share.
It runs ``experiment rooms`` on ``--rooms`` (room names without a partner state) in the
partner states ``--partner-states``, its table printed as that command prints it;
``--least-rank``: the threshold's least rank (the source's 2).

``peak``: the default bit source, but the speech band's level of a window is that of its
loudest ``--frame-ms`` (frames every half frame), or with ``--peak-weight`` below 1 that
weight of it plus the rest of the window's own level (dB); every window alike, so the
threshold still sets the false-alarm share. It runs ``experiment rooms`` as ``straddle``
does (``--seed``: its master seed).

``alarms``: the empty rooms' false alarms traced. The default runs (with controller_node's
check-ins, as ``experiment rooms`` runs them) of each room in ``--rooms`` whose belief
ever passes the attentive threshold, how long the robot had been silent there, and on which
window; for an empty room each such run: the step, the timer, the windows since the robot
last vocalized, and the belief ten steps before (a room with a partner: the summary only).

Run from the repository root::

    .venv/bin/python bench/probe_detection.py levels [--rooms tv-on+partner,...] [--runs 100]
        [--no-reference]
    .venv/bin/python bench/probe_detection.py timer [--rooms street,...] [--runs 100]
        [--controller random:0.125]
    .venv/bin/python bench/probe_detection.py table
    .venv/bin/python bench/probe_detection.py decisions [--rooms street,tv-on+partner]
        [--controller fixed:8]
    .venv/bin/python bench/probe_detection.py context [--rooms ...] [--runs 100]
        [--context-prior 1,1] [--gated] [--persistence exceedance|copula]
        [--persistence-share 0.2]
    .venv/bin/python bench/probe_detection.py gate [--rooms ...] [--runs 100]
    .venv/bin/python bench/probe_detection.py straddle [--rooms quiet,...] [--runs 100]
        [--partner-states absent,partner,arriving,leaving] [--least-rank 2]
    .venv/bin/python bench/probe_detection.py peak [--rooms quiet,...] [--runs 100]
        [--partner-states absent,partner] [--frame-ms 100] [--peak-weight 1] [--seed 0]
    .venv/bin/python bench/probe_detection.py alarms [--rooms street,street+partner] [--runs 300]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import dataclasses
import functools
import math
from collections.abc import Iterator

import numpy as np
from scipy import stats
from scipy.special import gammaln, logit

import infomax_contingency.audio.bitsources.background as background_source
from infomax_contingency.audio.background import BackgroundThreshold, level_and_faults
from infomax_contingency.audio.bitsources.background import LEAST_RANK, BackgroundSource
from infomax_contingency.audio.bitsources.base import window_energy_db
from infomax_contingency.audio.bitsources.level import SpeechBandLevel
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import ENERGY_FLOOR
from infomax_contingency.cli.main import main as command_line
from infomax_contingency.core.controllers import Controller, PolicyController, default_check_in
from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    ModelParams,
    Statistic,
    Withheld,
    belief_from_log_odds,
    betaln,
    expit,
    log_odds,
    period_of,
)
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.posture import ATTENTIVE_ABOVE, BORED_BELOW
from infomax_contingency.eval.rooms import controller_specs, run_room
from infomax_contingency.eval.rooms import running as rooms_running
from infomax_contingency.eval.rooms.config import RoomsConfig
from infomax_contingency.eval.rooms.running import RoomRun
from infomax_contingency.eval.rooms.scoring import postures, settled_step
from infomax_contingency.sim.room_config import FakeRoomConfig

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
    return (
        float(log_odds(params, 0, 0, 0, 0))  # the prior's: nothing counted
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
    attentive = postures(beliefs, ATTENTIVE_ABOVE, BORED_BELOW)
    if not partner_room:
        return bool(attentive.any())
    settled = settled_step(attentive, run.partner, beliefs, BORED_BELOW, 0)
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
    background_active_prior: tuple[float, float] | np.ndarray, average: bool,
) -> np.ndarray:  # fmt: skip
    """Log odds of S = 1 after each step under the ``context`` probe's Markov model.

    ``contexts``: each step's context (0/1); the last :data:`BELIEF_MEMORY` counted windows
    count, as for the belief node. ``background_active_prior``: the Beta prior on the
    background's rate after an active window, one for every step or one per step (rows).
    With ``average`` the odds are those of the Bayesian average (even prior odds) of this
    model and the model's independent windows.
    """
    agent_prior = (params.b21, params.b22)
    step_priors = np.broadcast_to(np.asarray(background_active_prior, float), (run.y.size, 2))
    periods = period_of(params, run.z)
    counted: list[tuple[int, int, int]] = []
    prior_odds = float(log_odds(params, 0, 0, 0, 0))  # nothing counted: the prior's
    out = np.zeros(run.y.size)
    for t, period in enumerate(periods):
        if period in (AGENT, BACKGROUND):
            counted = [*counted, (0 if period == AGENT else 1, int(contexts[t]), int(run.y[t]))]
            counted = counted[-BELIEF_MEMORY:]
        background_priors = ((params.b31, params.b32), tuple(step_priors[t]))
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


QUADRATURE = (np.arange(16) + 0.5) / 16
"""Quantiles at which the posteriors of the exceedance rates are taken (16 each)."""


def exceedance_priors(params: ModelParams, run: RoomRun, share: float) -> np.ndarray:
    """Per step, a Beta prior on the background's rate after an active window, from levels.

    The room's persistence as the bit source could see it: each window is marked loud when
    its level exceeds the k-th loudest of the background windows known before it at the
    false-alarm share ``share`` (the default source's rank rule, no reference). Over pairs
    of consecutive background windows up to the step, the rate of loud after loud and of
    loud after quiet have Beta posteriors (uniform priors); their odds ratio, carried to the
    bits' rate (the mean of the model's prior on K3: odds ratios of exceedances change
    less with the level than the rates), gives a rate after an active window for every
    pair of quantiles of the two (:data:`QUADRATURE`); the prior has the mean and variance
    of those (the uncertainty of the estimate carried through: near-uniform while little
    is known). From the run's steps: the warm-up windows, which the bit source also has,
    give none.
    """
    rule = BackgroundThreshold(
        params.ts1, params.ts2, params.ta2, false_alarm=share, history=HISTORY_WINDOWS,
        warmup_windows=WARMUP_WINDOWS, ta1=params.ta1, reference=False, least_rank=LEAST_RANK,
    )  # fmt: skip
    background = period_of(params, run.z) == BACKGROUND
    counts = np.zeros((2, 2))  # [loud before, loud now]
    base_log_odds = math.log(params.b31 / params.b32)
    previous: bool | None = None
    priors = np.ones((run.y.size, 2))
    for t, (level, decision) in enumerate(zip(run.energy_db, run.u, strict=True)):
        loud = rule.push(float(level), decision=int(decision))
        current = bool(loud) if background[t] and loud is not None else None
        if previous is not None and current is not None:
            counts[int(previous), int(current)] += 1
        previous = current
        after_loud = stats.beta.ppf(QUADRATURE, counts[1, 1] + 1, counts[1, 0] + 1)
        after_quiet = stats.beta.ppf(QUADRATURE, counts[0, 1] + 1, counts[0, 0] + 1)
        log_ratio = logit(after_loud)[:, None] - logit(after_quiet)
        rates = expit(base_log_odds + log_ratio)
        mean = float(np.clip(rates.mean(), 1e-3, 1 - 1e-3))
        worth = max(mean * (1 - mean) / max(float(rates.var()), 1e-6) - 1, 1.0)
        priors[t] = (worth * mean, worth * (1 - mean))
    return priors


@functools.cache
def copula_persistence(rate: float) -> tuple[np.ndarray, np.ndarray]:
    """P(active | the window before active) against the correlation of consecutive levels.

    For Gaussian levels a share ``rate`` of which is above the threshold, on a grid of
    correlations (returned with it).
    """
    correlations = np.linspace(-0.95, 0.99, 195)
    edge = stats.norm.isf(rate)
    both = [
        stats.multivariate_normal.cdf([-edge, -edge], cov=[[1, r], [r, 1]])
        for r in correlations
    ]
    return correlations, np.asarray(both) / rate


def copula_priors(params: ModelParams, run: RoomRun, least_pairs: int = 4) -> np.ndarray:
    """Per step, a Beta prior on the background's rate after an active window, from levels.

    The room's persistence as the bit source could see it without a single active window:
    the rank correlation of consecutive background windows' levels up to the step, read as
    the correlation of Gaussian levels (2 sin(pi rho_s / 6)), gives the rate of an active
    window after an active one at the model's K3 (the mean of its prior), through the
    bivariate normal (:func:`copula_persistence`). The prior has that mean and the variance
    of the estimate (Fisher's z, standard error sqrt(1.06 / (n - 3)) for n pairs, carried
    through); uniform below ``least_pairs`` pairs. From the run's steps, as
    :func:`exceedance_priors`.
    """
    rate = params.b31 / (params.b31 + params.b32)
    correlations, persistence = copula_persistence(rate)
    background = period_of(params, run.z) == BACKGROUND
    pairs: list[tuple[float, float]] = []
    priors = np.ones((run.y.size, 2))
    for t in range(run.y.size):
        if t and background[t] and background[t - 1]:
            pairs.append((float(run.energy_db[t - 1]), float(run.energy_db[t])))
        n = len(pairs)
        if n < least_pairs:
            continue
        first, second = np.asarray(pairs).T
        rank_correlation = stats.spearmanr(first, second).statistic
        if not np.isfinite(rank_correlation):
            continue
        z = math.atanh(np.clip(2 * math.sin(math.pi * rank_correlation / 6), -0.95, 0.99))
        spread = math.sqrt(1.06 / max(n - 3, 1))
        low, mean, high = np.interp(
            np.tanh([z - spread, z, z + spread]), correlations, persistence
        )
        mean = float(np.clip(mean, 1e-3, 1 - 1e-3))
        variance = max(((high - low) / 2) ** 2, 1e-6)
        worth = max(mean * (1 - mean) / variance - 1, 1.0)
        priors[t] = (worth * mean, worth * (1 - mean))
    return priors


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
    persistence: str = "",
    persistence_share: float = 0.2,
) -> None:
    """Print the ``context`` probe (the module's docstring); ``gated``: the gated table decides.

    ``persistence``: also with the prior after an active window from the room's levels,
    ``exceedance`` (:func:`exceedance_priors` at ``persistence_share``) or ``copula``
    (:func:`copula_priors`).
    """
    spec = controller_specs(params, ["optimal"])[0][1]
    variants = {"Markov": False, "average with independent": True}
    for room in rooms:
        partner_room = room.endswith("+partner")
        results: dict[str, list] = {"independent (the default)": []} | {v: [] for v in variants}
        cells = np.zeros((2, 2, 2))  # [agent 0 / background 1, context, bit] over the runs
        estimates: list[float] = []
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
            if persistence:
                priors = (
                    copula_priors(params, run)
                    if persistence == "copula"
                    else exceedance_priors(params, run, persistence_share)
                )
                estimates.append(priors[-1, 0] / priors[-1].sum())
                for name, average in variants.items():
                    odds = context_log_odds(params, run, contexts, priors, average)
                    results.setdefault(f"{name}, {persistence}", []).append(
                        outcome(run, odds, partner_room)
                    )
        shares = "; ".join(
            f"{period} after {'an active' if context else 'a quiet'} window"
            f" {cells[which, context, 1] / max(cells[which, context].sum(), 1):.3f}"
            f" ({cells[which, context].sum() / runs:.1f} per run)"
            for which, period in enumerate(("agent", "background"))
            for context in (0, 1)
        )
        after_active = cells[:, 1].sum(axis=0)
        print(f"{room:<24} active share: {shares}; any counted window after an active one"
              f" {after_active[1] / max(after_active.sum(), 1):.3f}")  # fmt: skip
        if estimates:
            print(f"{room:<24} {persistence} estimate of that rate at 60 s: median"
                  f" {np.median(estimates):.2f}, 10-90 % {np.quantile(estimates, 0.1):.2f}-"
                  f"{np.quantile(estimates, 0.9):.2f}")  # fmt: skip
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

    def gated(spec: str, params: ModelParams, rng: np.random.Generator,
              check_in: object = None) -> Controller:
        controller = make(spec, params, rng)  # the table alone, as when this was measured
        if isinstance(controller, PolicyController):
            return QuietGatedController(controller.table, params)
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


def _crossing_of_run(args: tuple[ModelParams, str, str, int]) -> tuple[int, int, int, str] | None:
    """Where one run's belief first passes the attentive threshold (None: never).

    Returns the step (from 1), the timer there, the windows since the robot last vocalized
    and the run in words.
    """
    params, room, spec, k = args
    run = run_room(params, room, spec, "background", 60.0, 0, k, BELIEF_MEMORY,
                   default_check_in(params))  # fmt: skip
    above = np.flatnonzero(run.belief > ATTENTIVE_ABOVE)
    if not above.size:
        return None
    step = int(above[0])
    asked = np.flatnonzero(run.u[:step])
    silent = step - int(asked[-1]) if asked.size else step + 1
    return step + 1, int(run.z[step]), silent, (
        f"{room:<16} run {k:3d}: P(S=1) {run.belief[step]:.3f} at step {step + 1}, timer"
        f" {int(run.z[step])}, {silent} windows after the last vocalization; ten steps before"
        f" {run.belief[max(step - 10, 0)]:.2f}")  # fmt: skip


def probe_alarms(params: ModelParams, rooms: list[str], runs: int) -> None:
    """Print the ``alarms`` probe (the module's docstring)."""
    spec = controller_specs(params, ["optimal"])[0][1]
    with concurrent.futures.ProcessPoolExecutor(2) as pool:
        for room in rooms:
            tasks = [(params, room, spec, k) for k in range(runs)]
            crossed = [c for c in pool.map(_crossing_of_run, tasks, chunksize=10) if c]
            silent = np.array([c[2] for c in crossed])
            on_background = np.mean([c[1] > params.ta2 for c in crossed]) if crossed else 0.0
            print(f"{room}: {len(crossed)} of {runs} runs ever attentive; windows after the last"
                  f" vocalization there: median {np.median(silent) if crossed else 0:g}, 10 or more"
                  f" in {np.mean(silent >= 10) if crossed else 0:.2f}; on a background window in"
                  f" {on_background:.2f}")  # fmt: skip
            for *_, words in crossed if "+" not in room else ():
                print(f"  {words}")


@contextlib.contextmanager
def straddled_levels(least_rank: int) -> Iterator[None]:
    """Within the block, the default source's level is the ``straddle`` probe's."""
    own_level = BackgroundSource._level
    source_least_rank = background_source.LEAST_RANK

    def straddled(self: BackgroundSource, x: np.ndarray) -> float:
        level = own_level(self, x)
        previous = getattr(self, "previous_window", None)
        self.previous_window = x.copy()
        if previous is None or previous.size != x.size:
            return level
        half = x.size // 2
        span_level, _ = level_and_faults(np.concatenate((previous[half:], x[:half])))
        self.last_level_db = max(level, span_level)
        return self.last_level_db

    BackgroundSource._level = straddled  # type: ignore[method-assign]
    background_source.LEAST_RANK = least_rank
    try:
        yield
    finally:
        BackgroundSource._level = own_level  # type: ignore[method-assign]
        background_source.LEAST_RANK = source_least_rank


def probe_straddle(rooms: str, runs: int, partner_states: str, least_rank: int) -> None:
    """Print the ``straddle`` probe: ``experiment rooms`` with the straddled level."""
    with straddled_levels(least_rank):
        status = command_line([
            "experiment", "rooms", "--rooms", rooms, "--partner-states", partner_states,
            "--controllers", "optimal", "--runs", str(runs),
        ])  # fmt: skip
    if status:
        raise SystemExit(status)


ALL_ROOMS = (
    "quiet,office,open-office,poster-session,cafe,tv-on,living-room,tv-switched-on,crowd-grows,"
    "kitchen,street,home-office"
)
"""Rooms of the ``straddle`` probe by default: RESULTS.md section 7's first twelve."""
PEAK_ROOMS = f"{ALL_ROOMS},playroom,dog-home,laundry,vacuum-next-door"
"""Rooms of the ``peak`` probe by default: every room of RESULTS.md section 7."""


@contextlib.contextmanager
def peak_levels(frame_ms: float, weight: float) -> Iterator[None]:
    """Within the block, the speech band's level is the ``peak`` probe's (dB)."""
    own_level_db = SpeechBandLevel.level_db

    def peak_level_db(self: SpeechBandLevel, x: np.ndarray) -> float:
        if x.size == 0:
            return own_level_db(self, x)
        state = self._steady_state * float(np.mean(x)) if self._state is None else self._state
        y, self._state = self._sosfilt(self._sos, x, zi=state)
        frame = max(1, round(self.rate_hz * frame_ms / 1000.0))
        window_db = window_energy_db(y)
        if y.size <= frame:
            return window_db
        sums = np.concatenate(([0.0], np.cumsum(y * y)))
        starts = np.arange(0, y.size - frame + 1, max(1, frame // 2))
        loudest_db = 10.0 * math.log10(float(np.max(sums[starts + frame] - sums[starts])) / frame
                                       + ENERGY_FLOOR)  # fmt: skip
        return weight * loudest_db + (1.0 - weight) * window_db

    SpeechBandLevel.level_db = peak_level_db  # type: ignore[method-assign]
    try:
        yield
    finally:
        SpeechBandLevel.level_db = own_level_db  # type: ignore[method-assign]


def probe_peak(rooms: str, runs: int, partner_states: str, frame_ms: float, weight: float,
               seed: int) -> None:  # fmt: skip
    """Print the ``peak`` probe: ``experiment rooms`` with the loudest frame's level."""
    with peak_levels(frame_ms, weight):
        status = command_line([
            "experiment", "rooms", "--rooms", rooms, "--partner-states", partner_states,
            "--controllers", "optimal", "--runs", str(runs), "--seed", str(seed),
        ])  # fmt: skip
    if status:
        raise SystemExit(status)


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
        "probe",
        choices=("levels", "timer", "table", "decisions", "context", "gate", "straddle", "peak",
                 "alarms"),
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
    parser.add_argument(
        "--persistence",
        choices=("exceedance", "copula"),
        help="context: also with the prior after an active window estimated from the room's"
        " background levels",
    )
    parser.add_argument(
        "--persistence-share",
        type=float,
        default=0.2,
        help="context, --persistence exceedance: loud windows at this false-alarm share",
    )
    parser.add_argument(
        "--partner-states",
        default="absent,partner,arriving,leaving",
        help="straddle, peak: the partner states (as experiment rooms takes them)",
    )
    parser.add_argument(
        "--least-rank", type=int, default=LEAST_RANK, help="straddle: the threshold's least rank"
    )
    parser.add_argument("--frame-ms", type=float, default=100.0, help="peak: the frame, ms")
    parser.add_argument(
        "--peak-weight", type=float, default=1.0, help="peak: the loudest frame's weight, 0-1"
    )
    parser.add_argument("--seed", type=int, default=0, help="peak: experiment rooms' seed")
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
    if args.probe == "alarms":
        probe_alarms(params, (args.rooms or "street,tv-switched-on").split(","), args.runs)
        return
    if args.probe == "peak":
        if not (10.0 <= args.frame_ms <= 500.0 and 0.0 <= args.peak_weight <= 1.0):
            raise ValueError("--frame-ms must lie in [10, 500] and --peak-weight in [0, 1]")
        probe_peak(args.rooms or PEAK_ROOMS, args.runs, args.partner_states, args.frame_ms,
                   args.peak_weight, args.seed)  # fmt: skip
        return
    if args.probe == "straddle":
        if args.least_rank < 1:
            raise ValueError(f"--least-rank must be at least 1, got {args.least_rank}")
        probe_straddle(args.rooms or ALL_ROOMS, args.runs, args.partner_states, args.least_rank)
    elif args.probe == "levels":
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
        if not 0.05 < args.persistence_share <= 0.5:
            share = args.persistence_share
            raise ValueError(f"--persistence-share must lie in (0.05, 0.5], got {share}")
        probe_context(
            params, rooms, args.runs, (prior[0], prior[1]), args.gated,
            args.persistence or "", args.persistence_share,
        )  # fmt: skip
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
