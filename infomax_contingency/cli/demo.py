"""``infomax-contingency demo``: the whole node graph against a simulated room, in lockstep.

Starts mic_node, controller_node, belief_node, posture_node, speaker_node (dry run) and
fake_audio_node as separate processes, as the launch file would, with the installed
``config/robot.yaml`` and ``config/fake_room.yaml``, and watches them from this
process: one line per step (room time, bit, vocalization, belief, posture, ground truth)
and a verdict. By default a partner answers for the first 60 s and then leaves; the
graph runs in lockstep, so 120 s of room time take a few seconds.

mic_node's bit source is its default, ``background`` (the threshold the model calibrates
itself on the room's background windows): its first windows (about 6 s) are its warm-up
and give no bit, which mic_node says on ``no_step``, and the lockstep room goes on to its
next window. ``--wav FILE`` replays a recording through mic_node instead of the simulated
room; with ``--bit-source energy`` or ``speech_band`` its threshold is the k-means
calibration of the first ``--calibration-s`` seconds. The table shows each step at the
time of its window.

A run may be as long as ``--steps`` asks: the demo gives up only when no message has
arrived for :data:`STALL_TIMEOUT_S`. SIGINT (Ctrl-C), SIGTERM or SIGHUP stop every node
(each runs in a process group of its own, so only the demo receives a terminal's Ctrl-C),
end the demo with status 128 + the signal and "interrupted", after the table of the steps
complete. A demo killed outright (SIGKILL,
an OOM kill) leaves no node running: each ends with it (the kernel's parent-death signal,
:func:`~infomax_contingency.nodes.runtime.end_with_parent`).

``--record DIR``: DIR must be new and writable (tried before any node starts); a
recorder that stopped writing during the run (it keeps the graph running) makes the
demo fail, with its error line (status 1).

DDS stays on this machine: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a random
``ROS_DOMAIN_ID`` unless the environment sets them. The graph's processes announce
themselves every 0.5 s (``config/fastdds_demo.xml``, :func:`demo_dds_profile`) unless the
user chose a Fast DDS profile. This module imports rclpy only when the demo runs, so the
command line stays light.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, MutableMapping
from pathlib import Path
from typing import Any

from infomax_contingency.audio.bitsources import BIT_SOURCES
from infomax_contingency.cli.demo_checks import (
    DEMO_CALIBRATION_S,
    DEMO_LEAVE_S,
    check_arguments,
    demo_partner_times,
    finite_number,
    log_messages,
    no_step,
    node_failure,
    recording_failure,
)
from infomax_contingency.cli.demo_output import (
    print_run,
    print_run_so_far,
    print_verdict,
    step_postures,
)
from infomax_contingency.cli.formatting import GivenOption, seed
from infomax_contingency.core.posture import ATTENTIVE_ABOVE, BORED_BELOW
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.room_config import PRESETS

CONNECT_TIMEOUT_S = 180.0
"""Seconds the nodes may take to come up and connect before the demo gives up."""
STALL_TIMEOUT_S = 30.0
"""Seconds the running graph may go without a single message before the demo gives up
(a no-progress watchdog: a run of any length is fine while steps keep coming)."""

LOCKSTEP_TIMEOUT_S = 10.0
"""Seconds the demo's clock node (room, or mic replaying a file) waits for a window's
decision before it releases the next window anyway (config/robot.yaml: 2 s, for a robot
that must go on). The demo is a reproducible run: a loaded machine may pause a node for
seconds, and a released window is a different run. A release is still reported."""


def register_demo(subparsers: argparse._SubParsersAction) -> None:
    """``demo``: the node graph against the simulated room (or a wav file), in lockstep."""
    parser = subparsers.add_parser(
        "demo",
        help="run the whole node graph against a simulated room (or a wav file), in lockstep",
        description=__doc__.split("\n\n")[0] + " " + __doc__.split("\n\n")[1],
    )
    parser.add_argument("--steps", type=int, default=240, help="windows of room time (default 240)")
    # The simulated room's options note that they were given (GivenOption): with --wav
    # they are refused, their default values typed out too.
    parser.add_argument("--seed", type=seed, default=1, action=GivenOption,
                        help="seed of the room (default 1)")  # fmt: skip
    parser.add_argument("--room", choices=tuple(PRESETS), default="responsive",
                        action=GivenOption, help="room (default responsive)")  # fmt: skip
    parser.add_argument(
        "--leave-at",
        type=finite_number,
        action=GivenOption,
        default=None,
        metavar="SECONDS",
        help=f"room time the partner leaves; negative: stays (default {DEMO_LEAVE_S:g} in the"
        " responsive room; any other room keeps its own: office+partner stays, office+leaving"
        " leaves at 20 s, office has nobody)",
    )
    parser.add_argument(
        "--memory",
        type=int,
        default=60,
        help="observations the belief remembers; 0 = all (default 60)",
    )
    parser.add_argument(
        "--wav", metavar="FILE", help="replay this WAV file instead of the simulated room"
    )
    parser.add_argument(
        "--calibration-s",
        type=finite_number,
        action=GivenOption,  # refused without a k-means calibration, its default typed too
        default=DEMO_CALIBRATION_S,
        help="--wav, --bit-source energy or speech_band: s to calibrate on (default 10)",
    )
    parser.add_argument(
        "--bit-source",
        choices=tuple(BIT_SOURCES),
        default=None,
        help="how mic_node turns a window into a bit (default: mic_node's default,"
        " background, which gives no bit in its first 6 s of warm-up)",
    )
    parser.add_argument(
        "--record",
        metavar="DIR",
        help="also record the session as a rosbag2 (MCAP) bag in DIR (must not exist)",
    )
    parser.add_argument(
        "--no-record-audio",
        action="store_true",
        help="with --record: leave the 'audio' topic out of the bag (a bag of a few KB)",
    )
    parser.set_defaults(run=run_demo, given=frozenset())


def isolate_dds() -> str:
    """Keep DDS on this machine and off the default domain unless the user chose."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not os.environ.get("ROS_DOMAIN_ID", "").strip():
        os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(100, 199))
    return os.environ["ROS_DOMAIN_ID"]


FAST_DDS_PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
"""Where Fast DDS 2.x (Jazzy's) reads its XML profile file from, once per process."""

USER_DDS_PROFILE_VARIABLES = (FAST_DDS_PROFILE_VARIABLE, "FASTDDS_DEFAULT_PROFILES_FILE")
"""Variables by which a user names a Fast DDS profile file (the second: Fast DDS 3's name)."""

USER_DDS_PROFILE_FILE = "DEFAULT_FASTRTPS_PROFILES.xml"
"""The profile file Fast DDS loads from the working directory when no variable names one."""


def demo_dds_profile(environ: MutableMapping[str, str] = os.environ, cwd: Path | None = None
                     ) -> str:  # fmt: skip
    """Give the demo's own graph ``config/fastdds_demo.xml`` unless the user chose a profile.

    That profile makes the participants announce themselves every 0.5 s instead of 3 s:
    the demo's processes start together, and a node whose first announcements a peer
    missed was found only at the next one (start-up 4.6-8.1 s instead of 2.5-3.9 s,
    docs/ENVIRONMENT.md). The data path (heartbeats, resends) keeps Fast DDS's defaults,
    as on a robot. Sets
    :data:`FAST_DDS_PROFILE_VARIABLE` in ``environ``, which this process and the node
    processes read.

    The user's choice stands: a file named by a variable of
    :data:`USER_DDS_PROFILE_VARIABLES`, none with ``SKIP_DEFAULT_XML_FILE`` set, or
    :data:`USER_DDS_PROFILE_FILE` in ``cwd`` (default: the working directory).

    Returns the profile file in effect, "" for none.
    """
    for name in USER_DDS_PROFILE_VARIABLES:
        if environ.get(name, "").strip():
            return environ[name].strip()
    if environ.get("SKIP_DEFAULT_XML_FILE", "").strip():
        return ""
    if ((cwd or Path.cwd()) / USER_DDS_PROFILE_FILE).is_file():
        return USER_DDS_PROFILE_FILE
    environ[FAST_DDS_PROFILE_VARIABLE] = str(resource_path("config", "fastdds_demo.xml"))
    return environ[FAST_DDS_PROFILE_VARIABLE]


def describe_dds_profile(profile: str) -> str:
    """The profile as the demo's first line names it: the file's name, or "none"."""
    return Path(profile).name if profile else "none"


def _choose_bit_source(mic: dict[str, Any], args: argparse.Namespace) -> None:
    """Set mic_node's ``bit_source`` when ``--bit-source`` is given.

    A threshold source on a wav file is calibrated on its first ``--calibration-s`` seconds.
    """
    if args.bit_source is None:
        return
    mic["bit_source"] = args.bit_source
    if args.wav and args.bit_source in ("energy", "speech_band"):
        mic["threshold_mode"] = "calibrate"
        mic["calibration_s"] = args.calibration_s


def _nodes(args: argparse.Namespace) -> tuple[dict[str, dict[str, Any]], str]:
    """Per-node parameters (over the config files) and the node that sets the pace."""
    # controller, belief and this monitor, and the recorder: with the recorder counted,
    # three subscribers of 'sound_step' could be there before the controller is.
    listeners = 4 if args.record else 3
    # The decisions' listeners: mic, belief, the speaker, this monitor, the room or (wav)
    # nobody else, and the recorder.
    decision_listeners = 4 + (not args.wav) + bool(args.record)
    nodes: dict[str, dict[str, Any]] = {
        "controller_node": {"wait_for_listeners": decision_listeners},
        "belief_node": {"memory_steps": args.memory},
        "posture_node": {"attentive_above": ATTENTIVE_ABOVE, "bored_below": BORED_BELOW},
        "speaker_node": {"dry_run": True},
    }
    if args.record:
        nodes["recorder_node"] = {
            "directory": str(Path(args.record).resolve()),
            "record_audio": not args.no_record_audio,
        }
    if args.wav:
        nodes["mic_node"] = {
            "source": "wav",
            "wav_file": str(Path(args.wav).resolve()),
            "lockstep": True,
            "exit_at_end": True,
            "wait_for_listeners": listeners,
            "lockstep_timeout_s": LOCKSTEP_TIMEOUT_S,
        }
        _choose_bit_source(nodes["mic_node"], args)
        return nodes, "mic_node"
    room: dict[str, Any] = {
        "room": args.room,
        "seed": args.seed,
        "max_windows": args.steps,
        "lockstep_timeout_s": LOCKSTEP_TIMEOUT_S,
    }
    room["wait_for_truth_listeners"] = 2 if args.record else 1  # this monitor (+ recorder)
    if args.record and not args.no_record_audio:
        room["wait_for_listeners"] = 2  # mic_node and the recorder, which subscribes to
        # 'audio' once it sees the room's publisher: no audio before it is lost
    room.update(demo_partner_times(args))
    nodes["mic_node"] = {"source": "topic", "wait_for_listeners": listeners}
    _choose_bit_source(nodes["mic_node"], args)
    nodes["fake_audio_node"] = room
    return nodes, "fake_audio_node"


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # SIGHUP: a terminal closed


class Interrupted(BaseException):
    """A stop signal reached the demo: stop the nodes, exit 128 + the signal number."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def interrupted_by_signals() -> Iterator[None]:
    """Turn the first of :data:`STOP_SIGNALS` into :class:`Interrupted`; ignore later ones.

    Later signals are ignored so that stopping the nodes is not itself interrupted.
    The previous handlers come back on leaving.
    """
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        if not received:
            received.append(signum)
            raise Interrupted(signum)

    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def run_demo(args: argparse.Namespace) -> int:
    """Run the graph, print one line per step and the verdict; returns the exit status.

    Exit status 0 after a run, 1 if the graph failed, 2 for bad arguments, 130 / 143 / 129
    after SIGINT / SIGTERM / SIGHUP (every node process is stopped first).
    """
    check_arguments(args)
    domain = isolate_dds()
    profile = demo_dds_profile()
    nodes, clock = _nodes(args)
    source = (
        f"replaying {args.wav}" if args.wav else f"simulated {args.room} room, seed {args.seed}"
    )
    print(
        f"# demo: starting the node graph ({', '.join(nodes)}) in lockstep, {source}"
        f" (ROS_DOMAIN_ID={domain}, Fast DDS profile {describe_dds_profile(profile)})",
        flush=True,
    )
    try:
        with interrupted_by_signals():
            outcome = _run_graph(args, nodes, clock)
    except (Interrupted, KeyboardInterrupt) as stop:
        with contextlib.suppress(OSError):  # a closed terminal (SIGHUP) takes no table
            print_run_so_far(getattr(stop, "recorder", None), WINDOW_S, truth=not args.wav)
        signum = stop.signum if isinstance(stop, Interrupted) else signal.SIGINT
        name = signal.Signals(signum).name
        print(f"infomax-contingency demo: interrupted ({name}); nodes stopped", file=sys.stderr)
        return 128 + signum
    if isinstance(outcome, str):
        print(f"infomax-contingency demo: error: {outcome}", file=sys.stderr)
        return 1
    recorder, steps, elapsed, released, mic_warnings = outcome
    print_run(recorder, steps, WINDOW_S, truth=not args.wav)
    print_notes(clock, released, mic_warnings)
    print_verdict(recorder, steps, WINDOW_S, args, elapsed)
    return 0


WINDOW_S = 0.5
"""Window length of config/robot.yaml, seconds."""


def print_notes(clock: str, released: int, mic_warnings: list[str]) -> None:
    """Print what the run's verdict rests on besides the steps.

    A ``# note:`` line when the clock node released windows without their decision, and a
    line for each of mic_node's warnings (once each, in order: a dead input, ...).
    """
    if released:
        print(
            f"# note: {clock} released {released} window(s) without their decision after"
            f" {LOCKSTEP_TIMEOUT_S:g} s (a node was that slow): not the reproducible run"
        )
    for warning in dict.fromkeys(mic_warnings):
        print(f"# mic_node warned: {warning}")


def _run_graph(
    args: argparse.Namespace, nodes: dict[str, dict[str, Any]], clock: str
) -> tuple[Any, int, float, int, list[str]] | str:
    """Start the graph, wait for the run, stop every node; or why not.

    Returns (recorder, steps, seconds from the first start to the last step, windows the
    clock node released without their decision, mic_node's WARN lines).

    The nodes are stopped whatever happens (an error, :class:`Interrupted`).
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from infomax_contingency.nodes.graph_node import RELEASED_WINDOW
    from infomax_contingency.nodes.qos import LOSSLESS_READER_QOS
    from infomax_contingency.testing.graph import (
        GraphError,
        GraphProcesses,
        SpinThread,
        StepRecorder,
        start_graph,
    )

    files = [resource_path("config", "robot.yaml")]
    if not args.wav:
        files.append(resource_path("config", "fake_room.yaml"))
    with tempfile.TemporaryDirectory(prefix="infomax-demo-") as workdir:
        processes = GraphProcesses(workdir, parameter_files=files, own_process_group=True)
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        recorder = None
        try:
            # Keep-all: the monitor's queues cannot drop a message however it is scheduled.
            recorder = StepRecorder("demo_monitor", stream_qos=LOSSLESS_READER_QOS)
            with SpinThread(recorder):
                start = time.monotonic()
                try:
                    start_graph(processes, recorder, nodes, clock, CONNECT_TIMEOUT_S)
                except GraphError as error:
                    return node_failure(processes) or str(error).splitlines()[0]
                print(f"# demo: the graph is up; running ({clock} sets the pace)", flush=True)
                steps, failure = _wait_for_run(args, processes, recorder, clock)
                if failure:
                    return failure
                elapsed = time.monotonic() - start
                _wait_with_watchdog(lambda: len(recorder.posture) >= 1, recorder, 5.0)
                _wait_for_postures(recorder, steps)
            released = processes.log(clock).count(RELEASED_WINDOW)
        except Interrupted as stop:
            stop.recorder = recorder  # the steps so far are printed
            raise
        finally:
            _stop_graph(processes, recorder)
        mic_warnings = log_messages(processes.log("mic_node"), "WARN")
        outcome = recorder, steps, elapsed, released, mic_warnings
        lost = args.record and recording_failure(Path(args.record), processes.log("recorder_node"))
        if not lost and not outcome[1]:
            return no_step(args.wav or "the room", len(recorder.no_step),
                           processes.log("mic_node"))
        return lost or outcome


def _stop_graph(processes: Any, recorder: Any) -> None:
    """Stop every node process, then the monitor and ROS.

    A signal now must not cut the stopping short: it waits until every node is stopped,
    then interrupts (and the demo still exits 130 / 143).
    """
    import rclpy

    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        processes.stop_all()
        if recorder is not None:
            recorder.destroy_node()
        rclpy.try_shutdown()
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)


def _wait_for_run(args: argparse.Namespace, processes: Any, recorder: Any,
                  clock: str = "fake_audio_node") -> tuple[int, str]:
    """Wait until every step is recorded: (steps, "") or (steps so far, why not).

    With mic_node as the clock (a wav file, a live microphone with ``max_windows``) the
    run ends when mic_node exits; with the fake room after ``args.steps`` steps.
    """
    if clock == "mic_node":
        mic = processes.processes["mic_node"]
        ok = _wait_with_watchdog(
            lambda: mic.poll() is not None, recorder, STALL_TIMEOUT_S, processes
        )
        steps = len(recorder.sound)
        if ok and mic.returncode == 0:
            ok = _wait_with_watchdog(
                lambda: min(len(recorder.vocalize), len(recorder.belief)) >= steps,
                recorder,
                STALL_TIMEOUT_S,
                processes,
            )
        else:
            ok = False
    else:

        def stepped() -> int:  # the room's windows less those said to give no step
            return args.steps - len(recorder.no_step)

        ok = _wait_with_watchdog(
            # every column the table prints: the monitor's subscriptions are apart, and
            # its 'sound' once lagged its 'belief' (an IndexError at the table, under load)
            lambda: len(recorder.partner_present) >= args.steps
            and min(len(recorder.sound), len(recorder.vocalize), len(recorder.belief))
            >= stepped(),
            recorder,
            STALL_TIMEOUT_S,
            processes,
        )
        steps = stepped()
    if ok:
        return steps, ""
    lost = {topic: n for topic, n in recorder.lost.items() if n}
    if lost:
        return steps, (
            f"the demo's monitor lost messages {lost} (its own fault: it read too slowly;"
            " the graph itself may be fine)"
        )
    failure = node_failure(processes)
    if failure:
        return steps, failure
    return steps, (
        f"the graph made no progress for {STALL_TIMEOUT_S:g} s after"
        f" {recorder.counts()} messages ({processes.report()})"
    )


def _wait_with_watchdog(
    condition: Callable[[], bool],
    recorder: Any,
    stall_s: float,
    processes: Any = None,
    poll_s: float = 0.02,
) -> bool:
    """Poll ``condition`` while messages keep arriving: False after ``stall_s`` without one.

    With ``processes``, also False as soon as a node exited (unless ``condition`` holds).
    """
    seen, last_progress = -1, time.monotonic()
    while not condition():
        if processes is not None and processes.dead():
            return condition()
        total = sum(recorder.counts().values())
        now = time.monotonic()
        if total != seen:
            seen, last_progress = total, now
        elif now - last_progress > stall_s:
            return condition()
        time.sleep(poll_s)
    return True


def _wait_for_postures(recorder: Any, steps: int, poll_s: float = 0.02) -> None:
    """Wait, at most ``REPAIR_WAIT_S``, for the posture changes the recorded beliefs call for.

    A run at full speed ends within a second of its last change, and a posture message
    lost on the way is resent only at its writer's next heartbeat (3 s with Fast DDS's
    defaults): the table printed sooner showed the whole run ``bored``. If the changes
    never match (other thresholds in a parameter file, or a change replaced in the
    writer's one-deep history before its repair), the table falls back to arrival order.
    """
    from infomax_contingency.nodes.runtime import REPAIR_WAIT_S
    from infomax_contingency.testing.graph import wait_until

    wait_until(lambda: bool(step_postures(recorder.belief[:steps],
                                      [p for _, p in list(recorder.posture)])),
               REPAIR_WAIT_S, poll_s=poll_s)  # fmt: skip
