"""The statistic, the exact belief and the parameters, against independent references."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import integrate, special, stats

import brute_force
from infomax_contingency.core import model
from infomax_contingency.core.model import ModelParams, ParameterError, Statistic, StatisticTracker

PARAM_SETS = {
    "paper": ModelParams.named("paper"),
    "robot": ModelParams.named("robot"),
    "gaps_informative": ModelParams(
        dt=0.25,
        ts1=1,
        ts2=2,
        ta1=4,
        ta2=6,
        pi=0.3,
        b11=3,
        b12=1,
        b21=2,
        b22=5,
        b31=1.5,
        b32=4,
    ),
    "even_odds": ModelParams(dt=1.0, ts1=0, ts2=0, ta1=2, ta2=2, pi=0.5, b21=0.5, b22=0.5),
}


def log_integral(a: float, b: float, ones: int, zeros: int) -> float:
    """``log of the integral of k^ones (1-k)^zeros Beta(k; a, b) dk``, by scipy.integrate.quad.

    The likelihood is scaled by its peak so the integral stays well inside double range.
    """
    mode = (ones + a - 1) / max(ones + zeros + a + b - 2, 1e-9)
    mode = min(max(mode, 1e-6), 1 - 1e-6)
    log_peak = ones * math.log(mode) + zeros * math.log1p(-mode)

    def likelihood(k: float) -> float:
        if k <= 0 or k >= 1:
            return 0.0
        return math.exp(ones * math.log(k) + zeros * math.log1p(-k) - log_peak)

    # the prior's k^(a-1) (1-k)^(b-1) is quad's algebraic weight: exact at the ends
    with warnings.catch_warnings():  # quad's accuracy notes; the tolerance below decides
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        value = integrate.quad(
            likelihood,
            0,
            1,
            weight="alg",
            wvar=(a - 1, b - 1),
            limit=200,
            epsabs=0,
            epsrel=1e-11,
        )[0]
    return math.log(value) + log_peak - float(special.betaln(a, b))


def integrated_belief(params: ModelParams, p2: int, q2: int, p3: int, q3: int) -> float:
    """P(S=1 | counts) with the rates integrated out numerically (:func:`log_integral`)."""
    log_s1 = (log_integral(params.b21, params.b22, p2, q2)
              + log_integral(params.b31, params.b32, p3, q3))  # fmt: skip
    log_s0 = log_integral(params.b31, params.b32, p2 + p3, q2 + q3)
    lam = math.log(params.pi / (1 - params.pi)) + log_s1 - log_s0
    return 1 / (1 + math.exp(-lam))


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
def test_belief_equals_numerical_integration(name: str) -> None:
    params = PARAM_SETS[name]
    rng = np.random.default_rng(7)
    for _ in range(25):
        counts = [int(c) for c in rng.integers(0, 25, size=4)]
        expected = integrated_belief(params, *counts)
        assert model.belief(params, *counts) == pytest.approx(expected, rel=1e-7, abs=1e-12)


def test_belief_vectorised_equals_scalar() -> None:
    params = PARAM_SETS["gaps_informative"]
    counts = np.random.default_rng(3).integers(0, 40, size=(4, 5000))
    batch = model.belief(params, *counts)
    single = [model.belief(params, *column) for column in counts.T[:50]]
    assert np.allclose(batch[:50], single, rtol=0, atol=0)
    assert np.array_equal(
        model.belief(params, *counts), model.belief(params, *counts.astype(float))
    )


def test_extreme_counts_stay_finite_and_exact_in_log_space() -> None:
    params = ModelParams.named("paper")  # pi = 0.01
    responsive = Statistic(4, p2=3000, q2=10, p3=5, q3=5000)
    silent = Statistic(4, p2=10, q2=3000, p3=20, q3=6000)
    assert responsive.log_odds(params) > 1000 and responsive.belief(params) == 1.0
    assert silent.belief(params) < 1e-3
    for statistic in (responsive, silent):
        assert 0.0 <= statistic.entropy(params) < 0.02
        assert math.isfinite(statistic.log_odds(params))
    # far beyond double-precision belief, the entropy is still positive and accurate
    lam = responsive.log_odds(params)
    expected_bits = (lam + 1) * math.exp(-lam) / math.log(2)  # leading terms of H near b=1
    assert responsive.entropy(params) == pytest.approx(expected_bits, rel=1e-9)


def test_entropy_matches_definition() -> None:
    params = PARAM_SETS["even_odds"]
    for counts in [(0, 0, 0, 0), (3, 1, 0, 5), (0, 7, 2, 2)]:
        b = model.belief(params, *counts)
        assert model.entropy(params, *counts) == pytest.approx(
            brute_force.entropy_bits(b), abs=1e-14
        )
    assert model.entropy(params, 0, 0, 0, 0) == pytest.approx(1.0)  # pi = 0.5, no data


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
def test_predictive_probability_equals_ratio_of_evidences(name: str) -> None:
    params = PARAM_SETS[name]
    rng = np.random.default_rng(11)
    for _ in range(30):
        p2, q2, p3, q3 = (int(c) for c in rng.integers(0, 12, size=4))
        events = [("agent", 1)] * p2 + [("agent", 0)] * q2
        events += [("background", 1)] * p3 + [("background", 0)] * q3
        for label, where in ((model.AGENT, "agent"), (model.BACKGROUND, "background")):
            expected = brute_force.probability_of_bit(params, events, where, 1)
            got = model.predictive_active(params, label, p2, q2, p3, q3)
            assert got == pytest.approx(expected, rel=1e-10)


def test_rate_variances_and_ratio() -> None:
    params = PARAM_SETS["gaps_informative"]
    var2, var3 = model.rate_variances(params, 3, 4, 1, 9)
    assert var2 == pytest.approx(stats.beta(2 + 3, 5 + 4).var())
    assert var3 == pytest.approx(stats.beta(1.5 + 1, 4 + 9).var())
    assert Statistic(0, 3, 4, 1, 9).variance_ratio(params) == pytest.approx(
        (var2 / 7) / (var3 / 10)
    )
    assert Statistic(0, 0, 0, 1, 9).variance_ratio(params) is None
    assert Statistic(0, 2, 0, 0, 0).variance_ratio(params) is None


def direct_statistic(
    params: ModelParams, z_initial: int, actions: list[int], bits: list[int], memory: int = 0
) -> Statistic:
    """The statistic after ``bits[0], actions[0], bits[1], ...`` by counting from scratch.

    ``bits`` has one more element than ``actions``: step t observes bits[t] then acts.
    """
    z_values = [z_initial]
    for u in actions:
        z_values.append(brute_force.next_timer(params, z_values[-1], u))
    counted = [(brute_force.period(params, z), z, y) for z, y in zip(z_values, bits, strict=True)]
    counted = [event for event in counted if event[0] != brute_force.SELF]
    if memory:
        counted = counted[-memory:]
    count = {
        key: sum(1 for where, _, y in counted if (where, y) == key)
        for key in [("agent", 1), ("agent", 0), ("background", 1), ("background", 0)]
    }
    lags: tuple[int, ...] = ()
    if params.k2_per_lag and count[("agent", 1)] + count[("agent", 0)]:
        lags = tuple(sum(1 for where, z, y in counted if where == "agent" and (z, y) == (lag, bit))
                     for lag in range(params.ta1, params.ta2 + 1) for bit in (1, 0))  # fmt: skip
    return Statistic(
        z_values[-1],
        count[("agent", 1)],
        count[("agent", 0)],
        count[("background", 1)],
        count[("background", 0)],
        lags,
    )


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
@pytest.mark.parametrize("memory", [0, 1, 7])
def test_statistic_equals_direct_counting(name: str, memory: int) -> None:
    params = PARAM_SETS[name]
    rng = np.random.default_rng(memory + 100)
    for _ in range(40):
        length = int(rng.integers(1, 60))
        z_initial = int(rng.integers(0, params.timer_long_ago + 1))
        bits = [int(b) for b in rng.integers(0, 2, size=length)]
        actions = [int(u) for u in rng.random(length - 1) < rng.uniform(0.05, 0.6)]
        tracker = StatisticTracker(params, memory=memory, z_initial=z_initial)
        statistic = Statistic(z_initial)
        for t, y in enumerate(bits):
            tracker.observe(y)
            if t < len(actions):
                tracker.act(actions[t])
        # the same history through Statistic.update (no memory)
        statistic = statistic.observe(params, bits[0])
        for u, y in zip(actions, bits[1:], strict=True):
            statistic = statistic.update(params, u, y)
        expected = direct_statistic(params, z_initial, actions, bits, memory)
        # the tracker's timer has not moved past the last bit: compare counts and timer
        assert tracker.statistic == expected
        if memory == 0:
            assert statistic == expected


def test_tracker_reset_and_bad_arguments() -> None:
    params = PARAM_SETS["robot"]
    tracker = StatisticTracker(params, memory=3)
    tracker.observe(1)
    tracker.act(1)
    tracker.reset()
    assert tracker.statistic == Statistic(params.timer_long_ago)
    with pytest.raises(ValueError, match="memory"):
        StatisticTracker(params, memory=-1)
    with pytest.raises(ValueError, match="z_initial"):
        StatisticTracker(params, z_initial=99)


def test_periods_and_timer() -> None:
    params = PARAM_SETS["gaps_informative"]  # self 1..2, agent 4..6, background 0, 3, 7
    labels = model.period_of(params, np.arange(params.n_timer_values))
    expected = [brute_force.period(params, z) for z in range(params.n_timer_values)]
    names = {model.SELF: "self", model.AGENT: "agent", model.BACKGROUND: "background"}
    assert [names[int(label)] for label in labels] == expected
    assert model.advance_timer(params, 3, 1) == 0
    assert model.advance_timer(params, 7, 0) == 7
    assert model.advance_timer(params, 2, 0) == 3
    # one value at a time (a simulation's step) gives the arrays' values, as Python ints
    timers = np.arange(params.n_timer_values)
    for u in (0, 1):
        after = model.advance_timer(params, timers, np.full_like(timers, u))
        for z in range(params.n_timer_values):
            for value, action in ((z, u), (np.int64(z), np.int64(u)), (np.int32(z), u),
                                  (np.uint8(z), u), (z, bool(u)), (z, np.bool_(u))):  # fmt: skip
                assert model.period_of(params, value) == labels[z]
                one = model.advance_timer(params, value, action)
                assert one == after[z] and type(one) is int
            assert type(model.period_of(params, np.int64(z))) is int
    outside = np.array([-3, -1, params.ta2 + 2, params.ta2 + 9, 2**40])  # not a timer value
    for z, label in zip(outside, model.period_of(params, outside), strict=True):
        assert model.period_of(params, int(z)) == label
    for z, after in zip(outside, model.advance_timer(params, outside, 0 * outside), strict=True):
        assert model.advance_timer(params, int(z), 0) == after


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"ts2": 3}, "ta1"),  # ts2 >= ta1
        ({"pi": 1.0}, "pi"),
        ({"pi": 0.0}, "pi"),
        ({"b21": 0.0}, "b21"),
        ({"b32": -1.0}, "b32"),
        ({"dt": 0.0}, "dt"),
        ({"ta2": 0}, "ta2"),
        ({"ts1": -1}, "ts1"),
        ({"ts1": 1.5}, "ts1"),
        ({"pi": float("nan")}, "pi"),
    ],
)
def test_invalid_parameters_are_refused_by_name(changes: dict, field: str) -> None:
    values = ModelParams.named("paper").to_dict() | {"ts2": 0} | changes
    with pytest.raises(ParameterError, match=field):
        ModelParams(**values)


def test_parameter_sets_and_yaml(tmp_path) -> None:
    paper = ModelParams.load("paper")
    assert (paper.dt, paper.ts1, paper.ts2, paper.ta1, paper.ta2, paper.pi) == (
        0.8,
        0,
        0,
        1,
        3,
        0.01,
    )
    robot = ModelParams.load("robot")
    assert (robot.dt, robot.ts1, robot.ts2, robot.ta1, robot.ta2) == (0.5, 0, 1, 2, 4)
    path = tmp_path / "params.yaml"
    path.write_text(
        "model:\n  dt: 0.5\n  ts1: 0\n  ts2: 1\n  ta1: 2\n  ta2: 4\n  pi: 0.01\n"
        "  b31: 0.5\n  b32: 9.5\n  k2_per_lag: true\n"
    )
    assert ModelParams.load(path) == robot
    assert ModelParams.load(path).digest() == robot.digest()
    path.write_text("{dt: 0.5, ts1: 0, ts2: 1, ta1: 2, ta2: 1000000000, pi: 0.01}\n")
    with pytest.raises(ParameterError, match="ta2 must be at most 10000 steps"):
        ModelParams.load(path)  # 65 bytes that took the machine's memory before
    path.write_text("dt: 0.5\nts1: 0\nts2: 1\nta1: 2\nta2: 4\npi: 0.01\nk2_per_lag: 1\n")
    with pytest.raises(ParameterError, match="k2_per_lag must be true or false, got 1"):
        ModelParams.load(path)
    # one K2 (false, the default) leaves the paper's digest; a table ignores k2_per_lag
    assert "k2_per_lag" not in paper.to_dict() and robot.to_dict()["k2_per_lag"] is True
    assert robot.for_table() == ModelParams(**{**robot.to_dict(), "k2_per_lag": False})
    path.write_text("dt: 0.5\nts1: 0\nts2: 1\nta1: 2\nta2: 4\npi: 0.01\nb99: 1\n")
    with pytest.raises(ParameterError, match="b99"):
        ModelParams.load(path)
    path.write_text("dt: 0.5\nts1: 0\n")
    with pytest.raises(ParameterError, match="missing.*ta1"):
        ModelParams.load(path)
    path.write_text("[1, 2")
    with pytest.raises(ParameterError, match="cannot read"):
        ModelParams.load(path)
    with pytest.raises(ParameterError, match="does not exist"):
        ModelParams.load(tmp_path / "nope.yaml")
    with pytest.raises(ParameterError, match="named sets"):
        ModelParams.load("papr")
    assert paper.differences(robot) and not paper.differences(ModelParams.named("paper"))


@pytest.mark.parametrize("name", ["robot", "gaps_informative_per_lag"])
def test_per_lag_belief_and_predictive_equal_brute_force(name: str) -> None:
    """One K2 per agent timer value, against direct counting with a rate per lag.

    The tracker's belief, entropy and predictive probability (brute_force.evidence).
    """
    params = PARAM_SETS["robot"] if name == "robot" else ModelParams(
        **{**PARAM_SETS["gaps_informative"].to_dict(), "k2_per_lag": True})
    rng = np.random.default_rng(17)
    for _ in range(40):
        length = int(rng.integers(1, 50))
        z = int(rng.integers(0, params.timer_long_ago + 1))
        tracker, events = StatisticTracker(params, z_initial=z), []
        for _ in range(length):
            y = int(rng.random() < 0.4)
            tracker.observe(y)
            events.append((brute_force.evidence(params, z), y))
            u = int(rng.random() < 0.3)
            tracker.act(u)
            z = brute_force.next_timer(params, z, u)
        statistic = tracker.statistic
        expected = brute_force.belief(params, events)
        assert statistic.belief(params) == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert statistic.entropy(params) == pytest.approx(
            brute_force.entropy_bits(expected), abs=1e-9)
        where = brute_force.evidence(params, z)
        if where != brute_force.SELF:
            assert statistic.predictive_active(params) == pytest.approx(
                brute_force.probability_of_bit(params, events, where, 1), rel=1e-9)



def test_per_lag_belief_equals_numerical_integration() -> None:
    """Each lag's rate integrated out numerically (scipy quad), independently of betaln."""
    params = PARAM_SETS["robot"]
    rng = np.random.default_rng(23)
    for _ in range(15):
        lags = tuple(int(c) for c in rng.integers(0, 12, size=2 * params.agent_lags))
        p3, q3 = (int(c) for c in rng.integers(0, 30, size=2))
        p2, q2 = sum(lags[0::2]), sum(lags[1::2])
        expected = (math.log(params.pi / (1 - params.pi))
                    + sum(log_integral(params.b21, params.b22, active, inactive)
                          for active, inactive in zip(lags[0::2], lags[1::2], strict=True))
                    + log_integral(params.b31, params.b32, p3, q3)
                    - log_integral(params.b31, params.b32, p2 + p3, q2 + q3))  # fmt: skip
        got = Statistic(4, p2, q2, p3, q3, lags).log_odds(params)
        assert got == pytest.approx(expected, rel=1e-8, abs=1e-9)
