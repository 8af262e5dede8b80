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

from infomax_contingency.eval.rooms.binarizers import (
    BINARIZERS,
    LEVEL_SOURCES,
    SHORT_NAME_SOURCE,
    BinarizerNameError,
    binarizer_options,
    make_binarizer,
)
from infomax_contingency.eval.rooms.config import (
    CONTROLLER_NAMES,
    FIXED_INTERVAL,
    PARTNER_STATE_NAMES,
    RoomsConfig,
    check_room_windows,
    controller_specs,
    room_seed,
)
from infomax_contingency.eval.rooms.experiment import (
    ROOMS_BASE_BYTES,
    ROOMS_CURVE_POINT_BYTES,
    ROOMS_ROW_BYTES,
    experiment_rooms,
    refuse_oversized_rooms,
    simulate_room_runs,
)
from infomax_contingency.eval.rooms.listening import (
    LISTENING_BINARIZER,
    RENDER_BASE_BYTES,
    RENDER_SAMPLE_BYTES,
    render_room,
)
from infomax_contingency.eval.rooms.running import (
    RoomRun,
    RoomTimeUpError,
    TimedWorld,
    run_room,
)
from infomax_contingency.eval.rooms.scoring import (
    RECOVERY_S,
    change_time_s,
    curve_points,
    postures,
    run_metrics,
    settled_step,
)
from infomax_contingency.eval.rooms.summaries import (
    contrast_bounds,
    operating_curves,
    summarise_room,
)

__all__ = [
    "BINARIZERS",
    "CONTROLLER_NAMES",
    "FIXED_INTERVAL",
    "LEVEL_SOURCES",
    "LISTENING_BINARIZER",
    "PARTNER_STATE_NAMES",
    "RECOVERY_S",
    "RENDER_BASE_BYTES",
    "RENDER_SAMPLE_BYTES",
    "ROOMS_BASE_BYTES",
    "ROOMS_CURVE_POINT_BYTES",
    "ROOMS_ROW_BYTES",
    "SHORT_NAME_SOURCE",
    "BinarizerNameError",
    "RoomRun",
    "RoomTimeUpError",
    "RoomsConfig",
    "TimedWorld",
    "binarizer_options",
    "change_time_s",
    "check_room_windows",
    "contrast_bounds",
    "controller_specs",
    "curve_points",
    "experiment_rooms",
    "make_binarizer",
    "operating_curves",
    "postures",
    "refuse_oversized_rooms",
    "render_room",
    "room_seed",
    "run_metrics",
    "run_room",
    "settled_step",
    "simulate_room_runs",
    "summarise_room",
]
