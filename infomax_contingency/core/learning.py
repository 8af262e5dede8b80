"""Infomax TD learning of the episodic policy (MODEL.md section 4), and faster variants.

Finite-horizon TD on the statistic ``a = (z, p2, q2, p3, q3)``. Values ``V_t(a)`` for
``t = 1 .. T`` live in arrays indexed like the solver's layers (timer z, then
:func:`~infomax_contingency.core.statespace.count_index`), so a trial step is a few list
lookups and reading off the greedy policy is one vectorised backward step per layer
(:func:`~infomax_contingency.core.solver.bellman_layer` on the learned next-layer values).

A trial draws ``s, k1, k2, k3`` from the prior, starts with zero counts and ``z_1``
uniform in ``1 .. ta2 + 1``, observes ``y_1``, and for ``t = 1 .. T-1`` acts and observes
the bits of the drawn rates. After the trial the visited statistics are backed up in
reverse order, ``V_T(a_T) = -H(a_T)`` and

* ``taken`` backup (MODEL.md, the plain algorithm):
  ``V_t(a_t) = -H(a_t) + sum_y P(y | a_t, u_t) V_{t+1}(f(a_t, u_t, y))`` for the action
  ``u_t`` taken (so exploratory actions are backed up too);
* ``best`` backup (real-time dynamic programming): the same with the better of the two
  actions, ``max_u``; the trial's exploratory actions then never lower a value.

Actions: with probability ``1 - epsilon`` the one maximising
``sum_y P(y | a_t, u) V_{t+1}(f(a_t, u, y))`` (ties: silence), else the other one.
Initial values:

* ``zero`` (MODEL.md): optimistic, since rewards are <= 0;
* ``entropy``: ``-H(a)``, the statistic's own reward with the future still counted as 0
  (optimistic too, but the present step is no longer free);
* ``listening``: the exact value of never vocalizing again from ``a``, computed from the
  model by the solver's policy evaluation. It is what listening alone yields, so no
  vocalization is spent learning it; every value is then a lower bound of the optimum,
  and ``best`` backups keep it one while only ever raising it.

Learning is counted in vocalizations made (exploratory ones included). ``plain`` in
:data:`METHODS` is MODEL.md section 4 with epsilon = 0.1; ``improved`` combines
``best`` backups, ``listening`` initial values and epsilon = 0.1.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    SELF,
    TIE_TOLERANCE,
    ModelParams,
    advance_timer,
    period_of,
)
from infomax_contingency.core.scoring import ActionsByStep, Scorer, episode_values, never_actions
from infomax_contingency.core.solver import bellman_layer, tuple_quantities
from infomax_contingency.core.statespace import n_count_tuples

BACKUPS = ("taken", "best")
INITIAL_VALUES = ("zero", "entropy", "listening")


@dataclasses.dataclass(frozen=True)
class LearningSettings:
    """How the learner explores and backs up.

    Attributes:
        epsilon: probability of taking the non-greedy action at each step.
        backup: ``taken`` (MODEL.md) or ``best`` (see the module docstring).
        initial: initial values, ``zero`` (MODEL.md), ``entropy`` or ``listening``.
    """

    epsilon: float = 0.1
    backup: str = "taken"
    initial: str = "zero"

    def __post_init__(self) -> None:
        if not 0.0 <= self.epsilon <= 1.0:
            raise ValueError(f"epsilon must be a probability in [0, 1], got {self.epsilon}")
        if self.backup not in BACKUPS:
            raise ValueError(f"backup must be one of {BACKUPS}, got {self.backup!r}")
        if self.initial not in INITIAL_VALUES:
            raise ValueError(
                f"initial values must be one of {INITIAL_VALUES}, got {self.initial!r}"
            )


METHODS: dict[str, LearningSettings] = {
    "plain": LearningSettings(epsilon=0.1, backup="taken", initial="zero"),
    "improved": LearningSettings(epsilon=0.1, backup="best", initial="listening"),
}
"""Named settings (see the module docstring; measured in docs/RESULTS.md)."""


class TDLearner:
    """Value tables and trials of infomax TD learning for one parameter set and horizon."""

    def __init__(
        self,
        params: ModelParams,
        horizon: int,
        settings: LearningSettings,
        rng: np.random.Generator,
    ):
        if horizon < 2:
            raise ValueError(f"learning horizon must be >= 2 steps, got {horizon}")
        self.params = params
        self.horizon = horizon
        self.settings = settings
        self.rng = rng
        self.tuples = tuple_quantities(params, horizon)
        n_timer = params.n_timer_values
        self._neg_entropy = self.tuples["neg_entropy"].tolist()
        self._periods = [period_of(params, z) for z in range(n_timer)]
        self._after = {key: index.tolist() for key, index in self.tuples["neighbours"].items()}
        # Per timer value z and action u: the next timer value and, for a counted period,
        # the predictive P(y=1) and the indices after y = 1 and y = 0, as Python lists.
        self._successors = []
        for z in range(n_timer):
            row = []
            for u in (0, 1):
                z_next = advance_timer(params, z, u)
                period = self._periods[z_next]
                if period == SELF:
                    row.append((z_next, None, None, None))
                else:
                    row.append(
                        (
                            z_next,
                            self.tuples[period].tolist(),
                            self._after[(period, 1)],
                            self._after[(period, 0)],
                        )
                    )
            self._successors.append(row)
        # values[t][z] is V_t over the count tuples of step t (counts sum to <= t).
        self.values: list[list[list[float]]] = [[]]
        if settings.initial == "listening":
            never = episode_values(params, horizon, never_actions(params))
        for t in range(1, horizon + 1):
            size = n_count_tuples(t)
            if settings.initial == "listening" and t < horizon:
                self.values.append(never[t - 1].tolist())
            elif settings.initial != "zero":  # V_T = -H(a) exactly; earlier layers optimistic
                layer = self._neg_entropy[:size]
                self.values.append([list(layer) for _ in range(n_timer)])
            else:
                self.values.append([[0.0] * size for _ in range(n_timer)])
        self.trials = 0
        self.vocalizations = 0

    def _expected_next(self, t: int, z: int, c: int, u: int) -> float:
        """``sum_y P(y | a, u) V_{t+1}(f(a, u, y))`` for ``a = (z, counts c)``."""
        z_next, p_active, after_active, after_inactive = self._successors[z][u]
        row = self.values[t + 1][z_next]
        if p_active is None:
            return row[c]
        p = p_active[c]
        return p * row[after_active[c]] + (1.0 - p) * row[after_inactive[c]]

    def trial(self) -> int:
        """Run one trial and its backups; returns the vocalizations it made."""
        params, rng, horizon = self.params, self.rng, self.horizon
        partner = rng.random() < params.pi
        k1 = rng.beta(params.b11, params.b12)
        k3 = rng.beta(params.b31, params.b32)
        k2 = rng.beta(params.b21, params.b22) if partner else k3
        rate = {SELF: k1, AGENT: k2, BACKGROUND: k3}
        rates = [rate[period] for period in self._periods]
        uniforms = rng.random(2 * horizon + 1).tolist()
        epsilon = self.settings.epsilon

        z = int(rng.integers(1, params.timer_long_ago + 1))
        c = self._observe(z, 0, uniforms[0] < rates[z])
        path = []
        made = 0
        for t in range(1, horizon):
            silent = self._expected_next(t, z, c, 0)
            vocal = self._expected_next(t, z, c, 1)
            u = 1 if vocal - silent > TIE_TOLERANCE else 0
            if uniforms[2 * t - 1] < epsilon:
                u = 1 - u
            path.append((z, c, u))
            made += u
            z = self._successors[z][u][0]
            c = self._observe(z, c, uniforms[2 * t] < rates[z])
        # Backups in reverse order.
        self.values[horizon][z][c] = self._neg_entropy[c]
        best = self.settings.backup == "best"
        for t in range(horizon - 1, 0, -1):
            z, c, u = path[t - 1]
            if best:
                future = max(self._expected_next(t, z, c, 0), self._expected_next(t, z, c, 1))
            else:
                future = self._expected_next(t, z, c, u)
            self.values[t][z][c] = self._neg_entropy[c] + future
        self.trials += 1
        self.vocalizations += made
        return made

    def _observe(self, z: int, c: int, y: bool) -> int:
        """Count index after observing bit y at timer value z (unchanged in the self period)."""
        period = self._periods[z]
        if period == SELF:
            return c
        return self._after[(period, int(y))][c]

    def greedy_actions(self) -> ActionsByStep:
        """The learned policy (epsilon = 0): greedy with respect to the learned values."""
        layers = {}
        for t in range(1, self.horizon):
            next_values = np.array(self.values[t + 1])
            _, actions = bellman_layer(self.params, self.tuples, next_values, t)
            layers[t] = actions
        return layers.__getitem__


@dataclasses.dataclass
class LearningCurve:
    """Score of the learned policy against vocalizations made.

    Attributes:
        method: name of the settings.
        settings: the settings.
        horizon: T.
        seed: random seed.
        vocalizations, trials, scores: the curve, one point per evaluation.
        first_reaching: vocalizations when the score first reached the target (None: never).
        staying_from: vocalizations from which the score stayed >= target until the end.
        target: the score target.
        seconds: wall-clock time of the run.
    """

    method: str
    settings: LearningSettings
    horizon: int
    seed: int
    vocalizations: list[int]
    trials: list[int]
    scores: list[float]
    first_reaching: int | None
    staying_from: int | None
    target: float
    seconds: float

    def to_dict(self) -> dict:
        """JSON-serialisable form."""
        record = dataclasses.asdict(self)
        record["settings"] = dataclasses.asdict(self.settings)
        return record


def learn(  # noqa: C901
    params: ModelParams,
    horizon: int,
    method: str | LearningSettings,
    budget: int,
    seed: int,
    evaluate_every: int = 1000,
    evaluate_growth: float = 0.0,
    target: float = 0.995,
    stop_at_target: bool = False,
    scorer: Scorer | None = None,
) -> tuple[LearningCurve, TDLearner]:
    """Learn until ``budget`` vocalizations, scoring the greedy policy exactly along the way.

    Args:
        params: model parameters.
        horizon: episode length T.
        method: a name in :data:`METHODS` or explicit settings.
        budget: vocalizations to learn for (the run stops after the trial that crosses it).
        seed: random seed (the run is deterministic given it).
        evaluate_every: score the learned policy every this many vocalizations...
        evaluate_growth: ...or, when later, once the vocalizations have grown by this
            fraction since the last score (log-spaced points on long runs).
        target: the score reported in ``first_reaching`` / ``staying_from``.
        stop_at_target: stop as soon as the score reaches the target.
        scorer: a :class:`Scorer` for ``params`` and ``horizon`` (made when not given).
    """
    if isinstance(method, str):
        if method not in METHODS:
            raise ValueError(f"unknown learning method {method!r}; methods: {sorted(METHODS)}")
        name, settings = method, METHODS[method]
    else:
        name, settings = "custom", method
    if budget < 1 or evaluate_every < 1:
        raise ValueError("budget and evaluation interval must be >= 1 vocalization")
    if not (math.isfinite(evaluate_growth) and evaluate_growth >= 0):
        raise ValueError(f"evaluation growth must be a finite number >= 0, got {evaluate_growth}")
    scorer = scorer or Scorer(params, horizon)
    learner = TDLearner(params, horizon, settings, np.random.default_rng(seed))
    started = time.perf_counter()
    curve = LearningCurve(name, settings, horizon, seed, [], [], [], None, None, target, 0.0)

    def record() -> float:
        score = scorer.score(learner.greedy_actions())
        curve.vocalizations.append(learner.vocalizations)
        curve.trials.append(learner.trials)
        curve.scores.append(score)
        if score >= target and curve.first_reaching is None:
            curve.first_reaching = learner.vocalizations
        return score

    record()
    next_evaluation = evaluate_every
    max_trials = 1000 * budget + 100_000  # a policy that stops vocalizing must still end
    while learner.vocalizations < budget and learner.trials < max_trials:
        learner.trial()
        if learner.vocalizations >= next_evaluation:
            next_evaluation = max(
                (learner.vocalizations // evaluate_every + 1) * evaluate_every,
                int(learner.vocalizations * (1.0 + evaluate_growth)),
            )
            if record() >= target and stop_at_target:
                break
    if curve.vocalizations[-1] != learner.vocalizations:
        record()
    staying = None
    for vocalizations, score in zip(
        reversed(curve.vocalizations), reversed(curve.scores), strict=True
    ):
        if score < target:
            break
        staying = vocalizations
    curve.staying_from = staying
    curve.seconds = time.perf_counter() - started
    return curve, learner


def format_vocalizations(count: int | None) -> str:
    """``12,345`` or ``never``."""
    return "never" if count is None else f"{count:,}"
