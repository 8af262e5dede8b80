"""Sessions: recorder CPU and disk per hour, replay speed.

1. **Recorder** (in this process, fed by a probe as fast as it takes them): CPU seconds
   and bag bytes per window of the graph's traffic (sound, sound_step, sound_energy,
   vocalize, vocalize_step, belief and, with ``--audio``, one 0.5 s window of 16 kHz
   float32 audio), extrapolated to one hour of real time (7,200 windows of 0.5 s) as a
   percentage of one core and MB per hour. This is an extrapolation from a burst of
   ``--windows`` windows, not an hour-long run; the diagnostics traffic (about six
   small messages a second) is left out.
2. **Replay** (``--actions recorded``, offline): steps per second over the committed
   ``test/data/session_demo`` bag (120 steps) and over a ``--replay-steps`` session made
   offline (the bit-level responsive room, rule controller), with the bag read included
   and excluded.

Run from the repository root::

    .venv/bin/python bench/bench_sessions.py [--windows 2000] [--audio] [--replay-steps N]
"""

from __future__ import annotations

import argparse
import array
import os
import sys
import tempfile
import time
from pathlib import Path

WINDOW_S = 0.5
AUDIO_RATE_HZ = 16_000


def bench_recorder(windows: int, audio: bool) -> None:
    """Record ``windows`` windows of traffic; print CPU and disk per real-time hour."""
    import rclpy
    from rclpy.parameter import Parameter
    from std_msgs.msg import Bool, Float32, Float32MultiArray, Float64, Int64MultiArray

    from infomax_contingency.nodes.recorder_node import RecorderNode
    from infomax_contingency.testing.stepped import Probe, SteppedExecutor

    rclpy.init()
    directory = Path(tempfile.mkdtemp()) / "bench_session"
    recorder = RecorderNode(parameter_overrides=[Parameter("directory", value=str(directory))])
    probe = Probe("bench_probe")
    executor = SteppedExecutor([recorder, probe])
    kinds = {"sound": Bool, "sound_step": Int64MultiArray, "sound_energy": Float32,
             "vocalize": Bool, "vocalize_step": Int64MultiArray, "belief": Float64}
    if audio:
        kinds["audio"] = Float32MultiArray
    pubs = {topic: probe.talk(topic, kind) for topic, kind in kinds.items()}
    samples = Float32MultiArray()
    samples.data = array.array("f", [0.01] * int(AUDIO_RATE_HZ * WINDOW_S))
    if audio:
        executor.run_until(lambda: "audio" in recorder.subscribed, "audio subscribed")
    for pub in pubs.values():
        executor.connected(pub)
    cpu_start = time.process_time()
    for step in range(1, windows + 1):
        pubs["sound"].publish(Bool(data=step % 3 == 0))
        pubs["sound_step"].publish(Int64MultiArray(data=[1, step, step % 3 == 0, 500_000]))
        pubs["sound_energy"].publish(Float32(data=-40.0))
        pubs["vocalize"].publish(Bool(data=step % 7 == 0))
        pubs["vocalize_step"].publish(Int64MultiArray(data=[1, step, step % 7 == 0, 5]))
        pubs["belief"].publish(Float64(data=0.5))
        if audio:
            pubs["audio"].publish(samples)
        executor.run_until(lambda s=step: recorder.counts["/belief"] >= s, "recorded",)
    executor.run_until(lambda: all(recorder.counts[f"/{t}"] >= windows for t in kinds),
                       "all recorded")
    cpu_s = time.process_time() - cpu_start  # recorder and probe: an upper bound
    executor.close()
    rclpy.try_shutdown()
    size = sum(f.stat().st_size for f in directory.iterdir())
    per_hour = 3600 / WINDOW_S / windows
    print(f"recorder ({'with' if audio else 'without'} 16 kHz audio), {windows} windows:"
          f" {cpu_s:.2f} CPU s in this process (recorder + publishing probe) ->"
          f" {100 * cpu_s * per_hour / 3600:.2f} % of a core at real time (upper bound,"
          f" extrapolated); bag {size / 1e6:.2f} MB -> {size * per_hour / 1e6:.0f} MB per hour")


def _offline_bag(directory: Path, steps: int) -> Path:
    """A session bag of ``steps`` steps of the responsive bit-level room (rule controller)."""
    import numpy as np

    from infomax_contingency.core.controllers import make_controller
    from infomax_contingency.core.model import ModelParams
    from infomax_contingency.eval.sessions import write_offline_session
    from infomax_contingency.sim.simulation import simulate
    from infomax_contingency.sim.world import make_room

    params = ModelParams.load("robot")
    rng = np.random.default_rng(0)
    records = simulate(params, make_controller("rule", params, rng),
                       make_room("responsive", params, rng), steps, rng)
    return write_offline_session(directory, [bool(r.y) for r in records],
                                 [bool(r.u) for r in records], [r.belief for r in records],
                                 params.dt)


def bench_replay(session_dir: Path, repeats: int) -> None:
    """Replay a session ``repeats`` times; print steps per second with and without the read."""
    from infomax_contingency.core.model import ModelParams
    from infomax_contingency.eval.sessions import load_session, replay_recorded

    params = ModelParams.load("robot")
    load_session(session_dir)  # the message definitions are built once per process
    start = time.perf_counter()
    steps = 0
    for _ in range(repeats):
        session = load_session(session_dir)
        steps += sum(1 for _ in replay_recorded(session, params))
    elapsed = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(repeats):
        sum(1 for _ in replay_recorded(session, params))
    compute = time.perf_counter() - start
    print(f"replay --actions recorded, {session_dir.name} ({steps // repeats} steps):"
          f" {steps / elapsed:,.0f} steps/s reading the bag included, {steps / compute:,.0f}"
          f" steps/s once read ({steps} steps replayed)")


def main() -> int:
    """Run both benchmarks."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--windows", type=int, default=2000)
    parser.add_argument("--audio", action="store_true", help="also record 16 kHz audio")
    parser.add_argument("--replay-steps", type=int, default=20_000,
                        help="steps of the offline session replayed (default 20000)")
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", "201")
    committed = Path(__file__).resolve().parents[1] / "test" / "data" / "session_demo"
    bench_replay(committed, repeats=20)
    with tempfile.TemporaryDirectory() as workdir:
        bench_replay(_offline_bag(Path(workdir) / "offline", args.replay_steps), repeats=3)
    bench_recorder(args.windows, args.audio)
    return 0


if __name__ == "__main__":
    sys.exit(main())
