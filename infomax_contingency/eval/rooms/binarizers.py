"""Experiment ``rooms``: the whole chain, from a room's sound to the robot's posture.

Each run is the node graph's lockstep loop offline, with the same code the nodes run:
the fake room (:class:`~infomax_contingency.sim.fake_room.FakeRoom`, as fake_audio_node),
window energies and a binarizer (as mic_node), a controller (as controller_node), the
exact belief with the belief node's sliding memory (:func:`~infomax_contingency.sim.loop.run_loop`'s
reporting statistic, as belief_node) and the posture rule with hysteresis
(:class:`~infomax_contingency.core.posture.PostureHysteresis`, as posture_node).

Measures per run (times are seconds of room time at the end of a window; the clock of an
``+arriving`` or ``+leaving`` room starts at the change,
:data:`~infomax_contingency.sim.rooms.ROOM_CHANGE_S`):

* **settled**: the first step from which the posture is correct until the end of the run
  — attentive while the partner is present, bored while not — counted from the change
  (from 0 in the other rooms); with no partner at the end, the belief must also have
  fallen below the lower posture threshold at that step (the robot *recognised* the
  empty room, rather than never having been shaken out of its initial bored posture).
  The seconds and the vocalizations until then; None if the posture is wrong at the end.
* **final posture** at the end of the run: a *false attentive* (attentive with nobody
  there) or a *missed partner* (bored while the partner is there).
* **bit contrast**: the bits of agent-period windows (timer ``ta1 .. ta2``) while the
  partner is present, of background windows (timer past ``ta2``) and of self-feedback
  windows, counted per run and pooled: the estimated P(active) the binarizer achieved
  in each, which the model calls K2, K3 and K1.
* **operating curve**: for a grid of upper posture thresholds and belief priors pi
  (the controller keeps its table), the median settling time in the ``+partner`` room
  against the share of runs in the empty room that turned attentive at any time.

Binarizers are made from a name by :func:`make_binarizer` (:data:`BINARIZERS`): every bit
source and threshold mode of mic_node, through the same
:func:`~infomax_contingency.audio.bitsources.make_bit_source`. Results are plain
JSON-serialisable dicts.
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.audio.bitsources import BIT_SOURCES, BitSource, make_bit_source
from infomax_contingency.audio.bitsources.base import NameArgument, SettingSpec
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    SELF,
    ModelParams,
    belief_from_log_odds,
    period_of,
)
from infomax_contingency.core.policy_table import RECEDING
from infomax_contingency.core.posture import ATTENTIVE, PostureHysteresis
from infomax_contingency.eval.experiments import (
    bootstrap_median,
    experiment_controller,
    obtain_table,
    wilson_interval,
)
from infomax_contingency.eval.information import information_bound
from infomax_contingency.eval.workers import worker_pool
from infomax_contingency.sim.fake_room import (
    AudioObservation,
    AudioWorld,
    FakeRoom,
    FakeRoomConfig,
    RoomWindow,
    as_transmitted,
)
from infomax_contingency.sim.loop import LoopStep, run_loop
from infomax_contingency.sim.rooms import (
    BACKGROUND_CHANGES_S,
    PARTNER_STATES,
    ROOM_CHANGE_S,
    ROOM_SOUNDS,
    audio_room_names,
    room_kind,
)

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
    if 0 <= last < len(words) - 1 and isinstance(declared[arguments[-1].setting].default, str):
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


LISTENING_BINARIZER = "fixed:-40"
"""``room-wav``'s default: the fixed threshold config/fake_room.yaml gives mic_node against
the fake room (a calibration on a room's own first 10 s is refused in the steadier rooms,
and the robot would stay silent)."""

PARTNER_STATE_NAMES: dict[str, str] = {
    "absent": PARTNER_STATES[0],
    "partner": PARTNER_STATES[1],
    "arriving": PARTNER_STATES[2],
    "leaving": PARTNER_STATES[3],
}
"""Partner states of ``RoomsConfig.partner_states`` -> suffix of the room's name."""

CONTROLLER_NAMES = ("optimal", "rule", "fixed", "random")
"""The controllers of the experiment (see :func:`controller_specs`)."""

FIXED_INTERVAL = 8
"""K of the fixed-interval controller (and 1/K of the random one): the K that detected
fastest in the efficiency experiment (docs/RESULTS.md section 6)."""


def controller_specs(
    params: ModelParams, names: Sequence[str], cache_dir: Path | None = None
) -> list[tuple[str, str]]:
    """(label, specification) of each named controller.

    ``optimal``: the receding table H = 24, M = 60 (controller_node's default);
    ``rule``: MODEL.md's rule, c = 9; ``fixed``: every :data:`FIXED_INTERVAL` steps;
    ``random``: with probability 1 / :data:`FIXED_INTERVAL` per step.
    """
    specs = []
    for name in names:
        if name == "optimal":
            _, path = obtain_table(params, RECEDING, 24, 60, cache_dir)
            specs.append(("optimal receding H=24 M=60", f"policy:{path}"))
        elif name == "rule":
            specs.append(("rule c=9", "rule:9"))
        elif name == "fixed":
            specs.append((f"fixed K={FIXED_INTERVAL}", f"fixed:{FIXED_INTERVAL}"))
        elif name == "random":
            specs.append((f"random P=1/{FIXED_INTERVAL}", f"random:{1.0 / FIXED_INTERVAL!r}"))
        else:
            raise ValueError(
                f"unknown controller {name!r}; controllers: {', '.join(CONTROLLER_NAMES)}"
            )
    return specs


@dataclasses.dataclass(frozen=True)
class RoomsConfig:
    """Size and settings of the rooms experiment.

    Attributes:
        params_name: model parameter set (the table's and the belief's).
        backgrounds: room sounds (keys of :data:`~infomax_contingency.sim.rooms.ROOM_SOUNDS`);
            each is run with the partner in each of ``partner_states``.
        partner_states: names of :data:`PARTNER_STATE_NAMES` (default all four; the
            operating curves need ``absent`` and ``partner``).
        controllers: names of :data:`CONTROLLER_NAMES`.
        binarizer: a name of :data:`BINARIZERS`.
        runs: runs per room and controller.
        seconds: room time per run, s.
        seed: master seed (a run's room seed depends on it, the room and the run number,
            not on the controller: every controller hears the same rooms).
        memory: the belief's sliding memory, steps (belief_node's ``memory_steps``).
        attentive_above: posture_node's upper threshold.
        bored_below: posture_node's lower threshold.
        curve_thresholds: upper thresholds of the operating curves.
        curve_priors: belief priors pi of the operating curves.
        jobs: worker processes (the results do not depend on it).
    """

    params_name: str = "robot"
    backgrounds: tuple[str, ...] = tuple(ROOM_SOUNDS)
    partner_states: tuple[str, ...] = tuple(PARTNER_STATE_NAMES)
    controllers: tuple[str, ...] = CONTROLLER_NAMES
    binarizer: str = "calibrate"
    runs: int = 100
    seconds: float = 60.0
    seed: int = 0
    memory: int = 60
    attentive_above: float = 0.9
    bored_below: float = 0.2
    curve_thresholds: tuple[float, ...] = (0.5, 0.7, 0.8, 0.9, 0.95, 0.99)
    curve_priors: tuple[float, ...] = (0.01, 0.05, 0.2, 0.5)
    jobs: int = 2

    def __post_init__(self) -> None:  # noqa: C901
        def fail(name: str, allowed: str) -> None:
            raise ValueError(
                f"experiment rooms: {name} = {getattr(self, name)!r}: must be {allowed}"
            )

        for background in self.backgrounds:
            if background not in ROOM_SOUNDS:
                known = ", ".join(ROOM_SOUNDS)
                raise ValueError(f"experiment rooms: unknown room {background!r}; rooms: {known}")
        if not self.backgrounds:
            fail("backgrounds", "at least one room")
        for name in self.partner_states:
            if name not in PARTNER_STATE_NAMES:
                fail("partner_states", f"names among {', '.join(PARTNER_STATE_NAMES)}")
        if not self.partner_states:
            fail("partner_states", "at least one partner state")
        for name in self.controllers:
            if name not in CONTROLLER_NAMES:
                fail("controllers", f"names among {', '.join(CONTROLLER_NAMES)}")
        if not self.controllers:
            fail("controllers", "at least one controller")
        make_binarizer(self.binarizer, 0.5)  # refuses a bad name now, not in a worker
        if self.runs < 1:
            fail("runs", ">= 1")
        if not (math.isfinite(self.seconds) and ROOM_CHANGE_S < self.seconds <= 3600):
            fail("seconds", f"more than the partner's change at {ROOM_CHANGE_S:g} s, at most 3600")
        if self.seed < 0:
            fail("seed", "a whole number >= 0")
        if self.memory < 0:
            fail("memory", ">= 0 steps (0: the whole history)")
        if not 0.0 <= self.bored_below < self.attentive_above <= 1.0:
            fail("attentive_above", f"in ({self.bored_below}, 1] above bored_below >= 0")
        for value in self.curve_thresholds:
            if not self.bored_below < value <= 1.0:
                fail("curve_thresholds", f"values in ({self.bored_below}, 1]")
        for value in self.curve_priors:
            if not 0.0 < value < 1.0:
                fail("curve_priors", "probabilities in (0, 1)")
        if self.jobs < 1:
            fail("jobs", ">= 1")

    def room_names(self) -> list[str]:
        """Every room of the experiment, each background in each of its partner states."""
        chosen = {PARTNER_STATE_NAMES[name] for name in self.partner_states}
        return [
            name
            for background in self.backgrounds
            for name, state in zip(audio_room_names(background), PARTNER_STATES, strict=True)
            if state in chosen
        ]


def room_seed(seed: int, room: str, run: int) -> int:
    """The fake room's seed of run ``run`` in ``room`` (fits fake_audio_node's ``seed``)."""
    key = [seed, zlib.crc32(room.encode()), run]
    return int(np.random.SeedSequence(key).generate_state(1)[0]) & 0x7FFFFFFF


class RoomTimeUpError(Exception):
    """The run's room time is over (raised by :class:`TimedWorld`)."""


class TimedWorld:
    """An :class:`AudioWorld` that ends after ``windows`` windows of room time.

    Calibration windows yield no step but do take room time, so the run is bounded by
    the room's clock, not by a number of steps.
    """

    def __init__(self, world: AudioWorld, windows: int) -> None:
        self.world = world
        self.windows = windows

    def observe(self) -> AudioObservation | None:
        """The next window's observation; :class:`RoomTimeUpError` once the time is over."""
        if self.world.room.windows_made >= self.windows:
            raise RoomTimeUpError
        return self.world.observe()

    def act(self, u: int) -> None:
        """As :meth:`AudioWorld.act`."""
        self.world.act(u)


@dataclasses.dataclass(frozen=True)
class RoomRun:
    """The steps of one run, as arrays (one entry per step).

    Attributes:
        window: room window of each step (calibration windows have no step).
        z: reporting timer during the window.
        y: the bits.
        u: the decisions.
        log_odds: log posterior odds of S=1 after the bit (natural log), with the
            belief node's memory.
        belief: P(S=1) after the bit, ``expit(log_odds)`` (as the belief node has it).
        partner: ground truth at the start of the window.
        energy_db: window energies.
    """

    window: np.ndarray
    z: np.ndarray
    y: np.ndarray
    u: np.ndarray
    log_odds: np.ndarray
    belief: np.ndarray
    partner: np.ndarray
    energy_db: np.ndarray


def run_room(
    params: ModelParams,
    room: str,
    controller_spec: str,
    binarizer: str,
    seconds: float,
    seed: int,
    run: int,
    memory: int,
) -> RoomRun:
    """One run of ``controller_spec`` in ``room`` for ``seconds`` of room time."""
    config = FakeRoomConfig.preset(room)
    fake_room = FakeRoom(config, room_seed(seed, room, run))
    rng = np.random.default_rng([seed, 1, run])
    controller = experiment_controller(controller_spec, params, rng)
    world = TimedWorld(
        AudioWorld(fake_room, make_binarizer(binarizer, config.window_s, config.rate_hz, params)),
        round(seconds / config.window_s),
    )
    steps: list[tuple[int, LoopStep[AudioObservation]]] = []
    try:
        for step in run_loop(world, controller, None, memory=memory):
            steps.append((fake_room.windows_made - 1, step))
    except RoomTimeUpError:
        pass
    log_odds = np.array([s.statistic.log_odds(params) for _, s in steps])
    return RoomRun(
        window=np.array([w for w, _ in steps], dtype=int),
        z=np.array([s.z for _, s in steps], dtype=int),
        y=np.array([s.observation.y for _, s in steps], dtype=int),
        u=np.array([s.u for _, s in steps], dtype=int),
        log_odds=log_odds,
        belief=np.array([float(belief_from_log_odds(lam)) for lam in log_odds]),
        partner=np.array([s.observation.partner_present for _, s in steps], dtype=bool),
        energy_db=np.array([s.observation.energy_db for _, s in steps]),
    )


def postures(beliefs: np.ndarray, attentive_above: float, bored_below: float) -> np.ndarray:
    """True where posture_node's rule is attentive after each belief (it starts bored)."""
    rule = PostureHysteresis(attentive_above, bored_below)
    out = np.zeros(beliefs.size, dtype=bool)
    for k, belief in enumerate(beliefs):
        rule.update(float(belief))
        out[k] = rule.posture == ATTENTIVE
    return out


def settled_step(
    attentive: np.ndarray,
    partner: np.ndarray,
    beliefs: np.ndarray,
    bored_below: float,
    first: int,
) -> int | None:
    """Index of the first step at or after ``first`` from which the posture stays correct.

    With nobody there at the end, the belief must also be below ``bored_below`` at that
    step. None if the posture is wrong at the end (or the run has no step).
    """
    if attentive.size == 0:
        return None
    wrong = np.flatnonzero(attentive != partner)
    start = max(first, int(wrong[-1]) + 1 if wrong.size else 0)
    if start >= attentive.size:
        return None
    if partner[-1]:
        return start
    sure = np.flatnonzero(beliefs[start:] < bored_below)
    return start + int(sure[0]) if sure.size else None


RECOVERY_S = 20.0
"""In a room whose background changes (:data:`~infomax_contingency.sim.rooms.BACKGROUND_CHANGES_S`),
the posture must be correct from this many seconds after the change to the end of the run."""


def change_time_s(room: str) -> float:
    """When the run's clock starts: the partner's arrival or departure, else 0."""
    state = room[room.index("+") :] if "+" in room else ""
    return ROOM_CHANGE_S if state in ("+arriving", "+leaving") else 0.0


def run_metrics(
    params: ModelParams,
    run: RoomRun,
    room: str,
    seconds: float,
    attentive_above: float,
    bored_below: float,
) -> dict[str, Any]:
    """The figures of one run (module docstring): settling, final posture, bit counts."""
    dt = params.dt
    attentive = postures(run.belief, attentive_above, bored_below)
    change = change_time_s(room)
    first = int(np.searchsorted(run.window * dt, change - 1e-9))
    settled = settled_step(attentive, run.partner, run.belief, bored_below, first)
    truth_at_end = FakeRoomConfig.preset(room).partner_present_at(seconds - dt)
    final_attentive = bool(attentive[-1]) if attentive.size else False
    background_change = BACKGROUND_CHANGES_S.get(room.partition("+")[0])
    correct_after_change = None
    if background_change is not None:
        late = run.window * dt >= background_change + RECOVERY_S - 1e-9
        correct_after_change = bool(np.all(attentive[late] == run.partner[late]))
    periods = period_of(params, run.z) if run.z.size else np.zeros(0, dtype=int)
    agent = (periods == AGENT) & run.partner
    background = periods == BACKGROUND
    self_period = periods == SELF
    return {
        "steps": int(run.y.size),
        "vocalizations": int(run.u.sum()),
        "settled_s": None if settled is None else (int(run.window[settled]) + 1) * dt - change,
        "settled_vocalizations": None if settled is None else int(run.u[first:settled].sum()),
        "partner_at_end": bool(truth_at_end),
        "false_attentive": bool(final_attentive and not truth_at_end),
        "missed_partner": bool(truth_at_end and not final_attentive),
        "ever_attentive": bool(attentive.any()),
        "correct_after_change": correct_after_change,
        "bits": {
            "agent": [int(run.y[agent].sum()), int(agent.sum())],
            "background": [int(run.y[background].sum()), int(background.sum())],
            "self": [int(run.y[self_period].sum()), int(self_period.sum())],
        },
    }


def curve_points(
    params: ModelParams,
    run: RoomRun,
    room: str,
    thresholds: Sequence[float],
    priors: Sequence[float],
    bored_below: float,
) -> dict[str, list[Any]]:
    """Points of the operating curves from one run's log odds.

    Per belief prior: per threshold, the settling seconds (partner room) or whether the
    posture turned attentive at any time (empty room); the other rooms give nothing. The
    belief under another prior pi' is exact from the log odds:
    ``lam' = lam - logit(pi) + logit(pi')`` (the likelihood ratio does not depend on pi).
    """
    if room.endswith(("+arriving", "+leaving")):
        return {}
    partner = room.endswith("+partner")
    out: dict[str, list[Any]] = {}
    for pi in priors:
        beliefs = belief_from_log_odds(run.log_odds - _logit(params.pi) + _logit(pi))
        row: list[Any] = []
        for threshold in thresholds:
            attentive = postures(beliefs, threshold, bored_below)
            if partner:
                settled = settled_step(attentive, run.partner, beliefs, bored_below, 0)
                row.append(None if settled is None else (int(run.window[settled]) + 1) * params.dt)
            else:
                row.append(bool(attentive.any()))
        out[repr(pi)] = row
    return out


def _logit(p: float) -> float:
    return math.log(p) - math.log1p(-p)


def _run_batch(
    config: RoomsConfig, controllers: list[tuple[str, str]], tasks: list[tuple[str, int]]
) -> list[dict]:
    """Every controller on each (room, run) of ``tasks``."""
    params = ModelParams.load(config.params_name)
    rows = []
    for room, run in tasks:
        for label, spec in controllers:
            result = run_room(
                params,
                room,
                spec,
                config.binarizer,
                config.seconds,
                config.seed,
                run,
                config.memory,
            )
            rows.append(
                {
                    "room": room,
                    "run": run,
                    "controller": label,
                    **run_metrics(
                        params,
                        result,
                        room,
                        config.seconds,
                        config.attentive_above,
                        config.bored_below,
                    ),
                    "curve": curve_points(
                        params,
                        result,
                        room,
                        config.curve_thresholds,
                        config.curve_priors,
                        config.bored_below,
                    ),
                }
            )
    return rows


def simulate_room_runs(config: RoomsConfig, controllers: list[tuple[str, str]]) -> list[dict]:
    """Rows of every run, in ``config.jobs`` processes (the same rows for any number)."""
    tasks = [(room, run) for room in config.room_names() for run in range(config.runs)]
    if config.jobs <= 1 or len(tasks) < 2:
        rows = _run_batch(config, controllers, tasks)
    else:
        with worker_pool(config.jobs) as pool:
            futures = [
                pool.submit(_run_batch, config, controllers, tasks[i :: config.jobs])
                for i in range(config.jobs)
            ]
            rows = [row for future in futures for row in future.result()]
    rooms = {room: k for k, room in enumerate(config.room_names())}
    order = {label: k for k, (label, _) in enumerate(controllers)}
    return sorted(rows, key=lambda row: (rooms[row["room"]], row["run"], order[row["controller"]]))


def _rate(counts: Sequence[Sequence[int]]) -> dict[str, Any]:
    active = sum(c[0] for c in counts)
    total = sum(c[1] for c in counts)
    return {
        "active": active,
        "windows": total,
        "p": active / total if total else math.nan,
        "ci": wilson_interval(active, total),
    }


def summarise_room(rows: Sequence[dict], seed: int) -> dict[str, Any]:
    """Figures with 95 % intervals of one controller in one room.

    Medians count runs that never settled as infinite (percentile-bootstrap interval,
    2,000 resamples); proportions have Wilson intervals.
    """
    rng = np.random.default_rng(seed)
    n = len(rows)
    seconds = np.array([math.inf if r["settled_s"] is None else r["settled_s"] for r in rows])
    vocalizations = np.array(
        [
            math.inf if r["settled_vocalizations"] is None else r["settled_vocalizations"]
            for r in rows
        ]
    )
    settled = int(np.isfinite(seconds).sum())
    ever = sum(r.get("ever_attentive", False) for r in rows)
    after_change = [
        r["correct_after_change"] for r in rows if r.get("correct_after_change") is not None
    ]
    false_attentive = sum(r["false_attentive"] for r in rows)
    missed = sum(r["missed_partner"] for r in rows)
    median_s, ci_s = bootstrap_median(seconds, rng)
    median_v, ci_v = bootstrap_median(vocalizations, rng)
    return {
        "runs": n,
        "settled": settled / n,
        "settled_ci": wilson_interval(settled, n),
        "settled_s_median": median_s,
        "settled_s_ci": ci_s,
        "settled_vocalizations_median": median_v,
        "settled_vocalizations_ci": ci_v,
        "wrong_at_end": (false_attentive + missed) / n,
        "wrong_at_end_ci": wilson_interval(false_attentive + missed, n),
        "false_attentive": false_attentive / n,
        "missed_partner": missed / n,
        "ever_attentive": ever / n,
        "ever_attentive_ci": wilson_interval(ever, n),
        "correct_after_change": sum(after_change) / len(after_change) if after_change else None,
        "correct_after_change_ci": wilson_interval(sum(after_change), len(after_change))
        if after_change
        else None,
        "vocalizations_per_run": float(np.mean([r["vocalizations"] for r in rows])),
        "steps_per_run": float(np.mean([r["steps"] for r in rows])),
        "p_active": {
            period: _rate([r["bits"][period] for r in rows])
            for period in ("agent", "background", "self")
        },
    }


def operating_curves(config: RoomsConfig, rows: Sequence[dict], label: str) -> dict[str, Any]:
    """Per background and belief prior: (threshold, median settling s, false-alarm share)."""
    rng = np.random.default_rng(config.seed)
    curves: dict[str, Any] = {}
    for background in config.backgrounds:
        partner = [
            r for r in rows if r["controller"] == label and r["room"] == f"{background}+partner"
        ]
        empty = [r for r in rows if r["controller"] == label and r["room"] == background]
        per_prior = {}
        for pi in config.curve_priors:
            points = []
            for k, threshold in enumerate(config.curve_thresholds):
                seconds = np.array(
                    [
                        math.inf if r["curve"][repr(pi)][k] is None else r["curve"][repr(pi)][k]
                        for r in partner
                    ]
                )
                alarms = sum(bool(r["curve"][repr(pi)][k]) for r in empty)
                median, ci = bootstrap_median(seconds, rng)
                points.append(
                    {
                        "attentive_above": threshold,
                        "settled_s_median": median,
                        "settled_s_ci": ci,
                        "detected": float(np.isfinite(seconds).mean())
                        if seconds.size
                        else math.nan,
                        "false_alarm": alarms / len(empty) if empty else math.nan,
                        "false_alarm_ci": wilson_interval(alarms, len(empty)),
                    }
                )
            per_prior[repr(pi)] = points
        curves[background] = per_prior
    return curves


def experiment_rooms(config: RoomsConfig, cache_dir: Path | None = None) -> dict[str, Any]:
    """The rooms experiment (module docstring): summaries per room and controller, curves."""
    params = ModelParams.load(config.params_name)
    for name in config.room_names():
        room_kind(name)  # every name is in the one registry
    controllers = controller_specs(params, config.controllers, cache_dir)
    rows = simulate_room_runs(config, controllers)
    summaries: dict[str, dict[str, Any]] = {}
    for label, _ in controllers:
        summaries[label] = {
            room: summarise_room(
                [r for r in rows if r["controller"] == label and r["room"] == room], config.seed
            )
            for room in config.room_names()
        }
    return {
        "experiment": "rooms",
        "config": dataclasses.asdict(config),
        "dt": params.dt,
        "params_pi": params.pi,
        "room_change_s": ROOM_CHANGE_S,
        "partner_states": list(PARTNER_STATES),
        "controllers": [label for label, _ in controllers],
        "rooms": config.room_names(),
        "summaries": summaries,
        "operating_curves": {
            label: operating_curves(config, rows, label) for label, _ in controllers
        },
        "information_bound": {
            label: contrast_bounds(params, summaries[label], config) for label, _ in controllers
        },
    }


def contrast_bounds(
    params: ModelParams, summaries: dict[str, dict[str, Any]], config: RoomsConfig
) -> dict[str, Any]:
    """Per background with a ``+partner`` room: the information bound of its bit contrast.

    P(active) in agent-period and background windows of the ``+partner`` runs
    (:func:`~infomax_contingency.eval.information.information_bound`, to the posture's
    ``attentive_above`` from the model's prior).
    """
    out: dict[str, Any] = {}
    for background in config.backgrounds:
        summary = summaries.get(f"{background}+partner")
        if summary is None:
            continue
        rates = summary["p_active"]
        if not (rates["agent"]["windows"] and rates["background"]["windows"]):
            continue
        out[background] = information_bound(
            rates["agent"]["p"], rates["background"]["p"], params, config.attentive_above
        )
    return out


class _RecordingRoom(FakeRoom):
    """A fake room that keeps every window's samples as the ``audio`` topic carries them."""

    def __init__(self, config: FakeRoomConfig, seed: int) -> None:
        super().__init__(config, seed)
        self.recorded: list[np.ndarray] = []

    def next_window(self) -> RoomWindow:
        window = super().next_window()
        self.recorded.append(as_transmitted(window.samples))
        return window


def render_room(
    room: str,
    seconds: float,
    seed: int,
    controller: str = "optimal",
    binarizer: str = LISTENING_BINARIZER,
    params_name: str = RoomsConfig.params_name,
    cache_dir: Path | None = None,
) -> tuple[np.ndarray, list[float], int]:
    """The sound of ``room`` for ``seconds`` with a controller deciding, for listening.

    The same closed loop as a run of the experiment (``seed`` is the fake room's own
    seed, as fake_audio_node's ``seed`` parameter). ``controller`` is a name of
    :data:`CONTROLLER_NAMES` or any controller specification of
    :func:`~infomax_contingency.core.controllers.make_controller`.

    Returns:
        float32 samples, the room times at which the robot's sound was commanded
        (seconds, the start of the window after each vocalizing decision), the rate (Hz).
    """
    params = ModelParams.load(params_name)
    config = FakeRoomConfig.preset(room)
    if not (math.isfinite(seconds) and config.window_s <= seconds <= 24 * 3600):
        raise ValueError(f"seconds = {seconds!r}: must be at least one window, at most a day")
    if not 0 <= seed < 2**31:
        raise ValueError(f"seed = {seed!r}: must be a whole number in 0 .. 2**31 - 1")
    spec = (
        controller_specs(params, [controller], cache_dir)[0][1]
        if controller in CONTROLLER_NAMES
        else controller
    )
    chosen = experiment_controller(spec, params, np.random.default_rng([seed, 1]))
    recording = _RecordingRoom(config, seed)
    windows = round(seconds / config.window_s)
    bits = make_binarizer(binarizer, config.window_s, config.rate_hz, params)
    world = TimedWorld(AudioWorld(recording, bits), windows)
    actions = []
    try:
        for step in run_loop(world, chosen, None):
            if step.u and recording.windows_made < windows:  # else played after the end
                actions.append(recording.windows_made * config.window_s)
    except RoomTimeUpError:
        pass
    return np.concatenate(recording.recorded), actions, recording.rate
