"""Live audio in the nodes: mic_node (source sounddevice) and speaker_node on virtual ALSA devices.

The nodes run as processes (``python -m infomax_contingency.nodes.<node>``) over real DDS,
with ``ALSA_CONFIG_PATH`` pointing at a configuration of this test only (see
alsa_devices.py), so the real sounddevice -> PortAudio -> ALSA path is exercised. The
test process only runs a probe node (on a hand-stepped executor); it never opens an audio
device.

The virtual devices have no clock: the microphone delivers its recording hundreds of
times faster than real time (so mic_node gets all its windows at once: ``queue_s`` holds
the whole recording and ``max_windows`` stops the node after it), and the loudspeaker
writes into a FIFO that the test reads at a steady pace (a plain file would grow by
hundreds of MB per second of silence). A microphone reading a FIFO that the test stops
feeding plays a device that goes silent and comes back.
"""

from __future__ import annotations

import dataclasses
import fcntl
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_msgs.msg import Bool, Float32, Int64MultiArray

from alsa_devices import VirtualAlsa
from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.resample import load_mono
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.audio.threshold import kmeans_threshold
from infomax_contingency.audio.wav import write_wav_int16
from infomax_contingency.core.model import ModelParams
from infomax_contingency.nodes.step_topics import StepDecision, decision_message, parse_bit
from infomax_contingency.testing.stepped import Probe, SteppedExecutor, StepTimeoutError

ROOT = Path(__file__).resolve().parent.parent
INTERACTION = Path(__file__).parent / "data" / "interaction.wav"
WINDOW_S = 0.5
OK = DiagnosticStatus.OK
TIMEOUT_S = 60.0
"""Seconds a node may take to start, run and stop before a test fails (generous)."""


# --------------------------------------------------------------------------- processes


class NodeProcess:
    """A node running as a process, its output in a log file."""

    def __init__(self, command: list[str], env: dict[str, str], log: Path) -> None:
        self.log = log
        with log.open("wb") as out:
            self.process = subprocess.Popen(
                command, cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=out
            )

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def wait(self, timeout: float = TIMEOUT_S) -> int:
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{self.log.name}: still running after {timeout} s\n{self.output()}")

    def stop(self) -> None:
        """SIGINT, then SIGTERM, then SIGKILL."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if self.process.poll() is not None:
                return
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                continue


@pytest.fixture
def spawn(tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """``spawn(node, parameters, env, namespace="")`` starts a node; all are stopped after."""
    started: list[NodeProcess] = []

    def start(
        node: str, parameters: dict[str, Any], env: dict[str, str], namespace: str = ""
    ) -> NodeProcess:
        command = [sys.executable, "-m", f"infomax_contingency.nodes.{node}", "--ros-args"]
        for name, value in parameters.items():
            command += ["-p", f"{name}:={value}"]
        if namespace:
            command += ["-r", f"__ns:=/{namespace}"]
        log = tmp_path / f"{namespace or 'root'}.{node}.log"
        started.append(NodeProcess(command, env, log))
        return started[-1]

    try:
        yield start
    finally:
        for node in started:
            node.stop()


# --------------------------------------------------------------------------- probe node


class Live:
    """The test's probe node on a hand-stepped executor: it records and answers the nodes."""

    def __init__(self) -> None:
        self.probe = Probe("live_probe")
        self.executor = SteppedExecutor([self.probe])
        self.diagnostics = self.probe.listen("/diagnostics", DiagnosticArray, 100)

    def record(self, topic: str, kind: type) -> list[tuple[Any, int]]:
        """Every message on ``topic`` with the time it was handled (system clock, ns)."""
        received: list[tuple[Any, int]] = []
        self.probe.listen(topic, kind, then=lambda msg: received.append((msg, time.time_ns())))
        return received

    def record_bits(self, namespace: str) -> list[bool]:
        """The bits on ``<namespace>/sound_step`` (whose subscriber starts a mic's clock)."""
        bits: list[bool] = []
        self.probe.listen(f"{namespace}/sound_step", Int64MultiArray,
                          then=lambda msg: bits.append(parse_bit(msg).bit))  # fmt: skip
        return bits

    def answer(self, namespace: str) -> list[bool]:
        """Answer each bit of ``<namespace>/sound_step`` with "do not vocalize"; the bits."""
        bits: list[bool] = []
        vocalize = self.probe.talk(f"{namespace}/vocalize_step", Int64MultiArray)

        def on_bit(msg: Int64MultiArray) -> None:
            bit = parse_bit(msg)
            bits.append(bit.bit)
            vocalize.publish(decision_message(StepDecision(bit.stream, bit.step, False, 1)))

        self.probe.listen(f"{namespace}/sound_step", Int64MultiArray, then=on_bit)
        return bits

    def statuses(self, node: str) -> list[dict[str, Any]]:
        """Key/values of every diagnostics status of ``node`` (level under ``_level``)."""
        statuses = [s for msg in self.diagnostics for s in msg.status if s.hardware_id == node]
        return [{kv.key: kv.value for kv in s.values} | {"_level": s.level} for s in statuses]

    def wait_for(self, condition: Callable[[], bool], what: str, *nodes: NodeProcess) -> None:
        """Step the probe until ``condition`` holds; fail with the nodes' logs if it does not."""
        try:
            self.executor.run_until(condition, what, deadline_s=TIMEOUT_S)
        except StepTimeoutError as error:
            logs = "\n".join(node.output() for node in nodes)
            pytest.fail(f"{error}\n{logs}")


@pytest.fixture
def probe() -> Iterator[Live]:
    rclpy.init()
    live = Live()
    try:
        yield live
    finally:
        live.executor.close()
        rclpy.try_shutdown()


# --------------------------------------------------------------------------- microphone


def mic_parameters(threshold_db: float, **extra: Any) -> dict[str, Any]:
    return {
        "window_s": WINDOW_S,
        "bit_source": "energy",
        "threshold_mode": "fixed",
        "threshold_db": threshold_db,
        "wait_for_listeners": 1,
        "start_delay_s": 0.2,
        **extra,
    }


def reference(wav: Path) -> tuple[np.ndarray, float, list[bool]]:
    """Energies of ``wav`` as the core computes them offline, a fixed threshold, the bits."""
    energies = window_energies_db(load_mono(wav), 16000, WINDOW_S)
    threshold = round(kmeans_threshold(energies), 1)
    bits = [bool(e > threshold) for e in energies]
    assert 0 < sum(bits) < len(bits) and np.min(np.abs(energies - threshold)) > 0.01
    return energies, threshold, bits


def heard_from(probe: Live, *nodes: NodeProcess, names: tuple[str, ...]) -> None:
    """Wait for diagnostics from every node in ``names``.

    The mic nodes start their step clock once ``sound`` has a subscriber; the probe
    subscribes only after this, so it surely receives their diagnostics to the end.
    """
    probe.wait_for(lambda: all(probe.statuses(name) for name in names), "diagnostics", *nodes)


def final_status(probe: Live, node: str, windows: int) -> dict[str, Any]:
    """The diagnostics a mic node publishes when it stops after ``windows`` bits."""
    probe.wait_for(
        lambda: any(s.get("bits_published") == str(windows) for s in probe.statuses(node)), node
    )
    return next(s for s in probe.statuses(node) if s.get("bits_published") == str(windows))


@pytest.mark.slow
def test_live_capture_publishes_the_bits_of_the_wav_source(
    tmp_path: Path, spawn: Callable[..., NodeProcess], probe: Live
) -> None:
    wav = tmp_path / "interaction16k.wav"  # the committed recording, at 16 kHz
    write_wav_int16(wav, load_mono(INTERACTION, 16000), 16000)
    energies, threshold, bits = reference(wav)
    n = len(bits)
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("fakemic", wav)
    alsa.write(default_capture="fakemic")

    live = spawn(
        "mic_node",
        mic_parameters(threshold, source="sounddevice", device=0, queue_s=60.0, max_windows=n),
        alsa.env(),
        "live",
    )
    replay = spawn(
        "mic_node",
        mic_parameters(threshold, source="wav", wav_file=wav, lockstep=True, exit_at_end=True),
        alsa.env(),
        "replay",
    )
    heard_from(probe, live, replay, names=("/live/mic_node", "/replay/mic_node"))
    live_bits = probe.record("live/sound", Bool)
    live_steps = probe.record_bits("live")
    live_energies = probe.record("live/sound_energy", Float32)
    replay_bits = probe.answer("replay")
    replay_energies = probe.record("replay/sound_energy", Float32)
    probe.wait_for(lambda: len(live_bits) >= n and len(replay_bits) >= n, f"{n} bits", live, replay)
    probe.wait_for(lambda: live.process.poll() is not None and replay.process.poll() is not None,
                   "both mic nodes to stop", live, replay)  # fmt: skip
    assert live.wait() == 0, live.output()
    assert replay.wait() == 0, replay.output()

    assert [msg.data for msg, _ in live_bits] == bits  # one per window, in order, none lost
    assert live_steps == bits and replay_bits == bits
    assert np.array_equal(
        np.array([msg.data for msg, _ in live_energies], np.float32), energies.astype(np.float32)
    )
    assert np.array_equal(
        np.array([msg.data for msg, _ in replay_energies], np.float32),
        energies.astype(np.float32),
    )
    out = live.output()
    assert "microphone: device '0' is [0] fakemic (ALSA," in out
    assert "Traceback" not in out and "[ERROR]" not in out
    status = final_status(probe, "/live/mic_node", n)  # published on stopping
    assert status["device"] == "fakemic" and status["device_rate"] == "16000"
    assert status["state"] == "connected" and status["windows_with_loss"] == "0"
    # the device runs far ahead of real time, so the queue overflows after the recording:
    # the counters are there, and no published window lost anything
    for key in ("overflows", "dropped_blocks", "lost_samples", "gaps", "reconnects"):
        assert status[key].isdigit(), (key, status)


@pytest.mark.slow
@pytest.mark.xdist_group("node_graphs")
@pytest.mark.parametrize(
    ("bit_source", "options"),
    [
        ("speech_band", {"threshold_mode": "noise_floor", "calibration_s": 2.0}),
        ("vad", {}),
    ],
)
def test_live_capture_with_a_bit_source_publishes_the_bits_of_the_wav_source(
    tmp_path: Path,
    spawn: Callable[..., NodeProcess],
    probe: Live,
    bit_source: str,
    options: dict[str, Any],
) -> None:
    """One smoke test per bit source that needs the samples: microphone = file = offline."""
    wav = tmp_path / "interaction16k.wav"
    write_wav_int16(wav, load_mono(INTERACTION, 16000), 16000)
    windows = load_mono(wav)
    windows = windows[: windows.size // 8000 * 8000].reshape(-1, 8000)
    offline = make_bit_source(bit_source, 16000, WINDOW_S, **options)
    bits = [bit for bit in (offline.push_window(w) for w in windows) if bit is not None]
    n = len(bits)
    assert 0 < sum(bits) < n
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("fakemic", wav)
    alsa.write(default_capture="fakemic")
    common = {"window_s": WINDOW_S, "bit_source": bit_source, "wait_for_listeners": 1,
              "start_delay_s": 0.2, **options}  # fmt: skip
    live = spawn(
        "mic_node",
        {**common, "source": "sounddevice", "device": 0, "queue_s": 60.0, "max_windows": n},
        alsa.env(),
        "live",
    )
    replay = spawn(
        "mic_node",
        {**common, "source": "wav", "wav_file": wav, "lockstep": True, "exit_at_end": True},
        alsa.env(),
        "replay",
    )
    heard_from(probe, live, replay, names=("/live/mic_node", "/replay/mic_node"))
    live_bits = probe.record_bits("live")
    replay_bits = probe.answer("replay")
    probe.wait_for(lambda: len(live_bits) >= n and len(replay_bits) >= n, f"{n} bits", live, replay)
    probe.wait_for(lambda: live.process.poll() is not None and replay.process.poll() is not None,
                   "both mic nodes to stop", live, replay)  # fmt: skip
    assert live.wait() == 0, live.output()
    assert replay.wait() == 0, replay.output()
    assert live_bits == bits and replay_bits == bits
    out = live.output()
    assert f"bit source {bit_source}" in out
    assert "Traceback" not in out and "[ERROR]" not in out
    status = final_status(probe, "/live/mic_node", n)
    assert status["bit_source"] == bit_source and status["windows_with_loss"] == "0"


@pytest.mark.slow
def test_live_capture_from_a_48khz_only_microphone_gives_the_same_bits(
    tmp_path: Path, spawn: Callable[..., NodeProcess], probe: Live
) -> None:
    wav = tmp_path / "interaction48k.wav"
    write_wav_int16(wav, load_mono(INTERACTION, 48000), 48000)
    energies, threshold, bits = reference(wav)  # the wav source's energies (resampled)
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("usb48", wav, only_rate=48000)
    alsa.write(default_capture="usb48")

    mic = spawn(
        "mic_node",
        mic_parameters(
            threshold, source="sounddevice", device="USB", queue_s=60.0, max_windows=len(bits)
        ),
        alsa.env(),
    )
    heard_from(probe, mic, names=("/mic_node",))
    live_bits = probe.record("sound", Bool)
    live_steps = probe.record_bits("")
    live_energies = probe.record("sound_energy", Float32)
    probe.wait_for(lambda: len(live_steps) >= len(bits), f"{len(bits)} bits", mic)
    probe.wait_for(lambda: mic.process.poll() is not None, "the mic node to stop", mic)
    assert mic.wait() == 0, mic.output()
    assert [msg.data for msg, _ in live_bits] == bits == live_steps
    assert np.array_equal(
        np.array([msg.data for msg, _ in live_energies], np.float32), energies.astype(np.float32)
    )
    out = mic.output()
    assert "microphone: device 'USB' is [0] usb48 (ALSA," in out
    assert "usb48 does not open at 16000 Hz" in out and "capturing at 48000 Hz" in out
    status = final_status(probe, "/mic_node", len(bits))
    assert status["device_rate"] == "48000" and status["rate"] == "16000"
    assert status["windows_with_loss"] == "0"


def noise(seconds: float, loud: list[tuple[float, float]], seed: int) -> np.ndarray:
    """Quiet hiss with loud noise in the ``(start, end)`` intervals (seconds), 16 kHz float32."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * 16000)) / 16000
    level = np.full(t.size, 0.001)
    for start, end in loud:
        level[(t >= start) & (t < end)] = 0.2
    return (level * rng.standard_normal(t.size)).astype("<f4")


@pytest.mark.slow
def test_live_microphone_that_stalls_is_reopened_and_the_gap_stays_a_gap(
    tmp_path: Path, spawn: Callable[..., NodeProcess], probe: Live
) -> None:
    window_s, threshold = 0.25, -40.0
    before = noise(2.0, [(0.5, 1.0), (1.5, 2.0)], seed=1)  # 8 windows
    after = noise(3.0, [(0.5, 1.5), (2.5, 3.0)], seed=2)  # 12 windows
    expected = [bool(e > threshold) for e in window_energies_db(before, 16000, window_s)]
    # short windows keep the test short; the mic refuses a window other than the model's dt
    model = tmp_path / "model_dt025.yaml"
    model.write_text(yaml.safe_dump({**dataclasses.asdict(ModelParams.named("robot")),
                                     "dt": window_s}))  # fmt: skip
    alsa = VirtualAlsa(tmp_path / "alsa")
    fifo = alsa.fifo_microphone("fifomic")
    alsa.write(default_capture="fifomic")
    # this process holds the FIFO open for reading and writing: PortAudio's probing of the
    # device (opening it for reading) does not block, and closing it ends every read
    fd = os.open(fifo, os.O_RDWR)
    fcntl.fcntl(fd, 1031, 1 << 20)  # F_SETPIPE_SZ: room for every part at once
    bits = probe.record("sound", Bool)
    steps = probe.record_bits("")
    try:
        mic = spawn(
            "mic_node",
            mic_parameters(threshold, source="sounddevice", device="fifo", window_s=window_s,
                           params=model),  # fmt: skip
            alsa.env(),
        )
        probe.wait_for(lambda: "at 16000 Hz, 1 channel" in mic.output(), "the microphone", mic)
        os.write(fd, before.tobytes())
        probe.wait_for(lambda: len(bits) >= len(expected), "the windows before the stall", mic)
        # no audio: after 1.5 s the device counts as gone; it is reopened (and starves again)
        probe.wait_for(lambda: "reconnected" in mic.output(), "a reconnection", mic)
        assert len(bits) == len(expected)  # nothing was published for the missing time
        os.write(fd, after.tobytes())
        probe.wait_for(lambda: len(bits) >= len(expected) + 10, "the windows after the gap", mic)
        probe.wait_for(
            lambda: any(s.get("gaps") == "1" for s in probe.statuses("/mic_node")),
            "diagnostics of the gap",
            mic,
        )
        status = next(s for s in probe.statuses("/mic_node") if s.get("gaps") == "1")
        published = [msg.data for msg, _ in bits]
        # 'sound' and 'sound_step' are two topics: the last stamped bits may still be on
        # their way here (under load the comparison once found one missing)
        probe.wait_for(lambda: len(steps) >= len(published), "every bit on sound_step", mic)
        assert steps[: len(published)] == published
    finally:
        os.close(fd)  # no writer left: the device's reads return, its streams close
    mic.stop()
    assert mic.process.returncode == 0, mic.output()
    assert published[: len(expected)] == expected
    # after the gap: the audio that came, window by window (the first block of it may go
    # to the stream that was given up), never made-up windows for the missing seconds
    resumed = published[len(expected) :]
    assert 10 <= len(resumed) <= 12 and 4 <= sum(resumed) <= 7, resumed
    assert int(status["disconnects"]) >= 1 and int(status["reconnects"]) >= 1
    out = mic.output()
    assert "microphone disconnected: no audio from fifomic for 1.5 s" in out
    assert re.search(r"audio gap of \d+\.\d\d s before window 8", out), out
    assert "Traceback" not in out and "[ERROR]" not in out


# --------------------------------------------------------------------------- missing devices


def test_missing_devices_stop_the_nodes_with_the_list_of_devices(
    tmp_path: Path, spawn: Callable[..., NodeProcess]
) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.microphone("fakemic", np.zeros(1600))
    alsa.speaker("fakespeaker")
    alsa.write(default_capture="fakemic", default_playback="fakespeaker")
    mic = spawn("mic_node", {"source": "sounddevice", "device": "nonexistent"}, alsa.env())
    speaker = spawn("speaker_node", {"dry_run": False, "device": "nonexistent"}, alsa.env())
    expected = {
        mic: ("no input device name contains 'nonexistent'", "[0] fakemic (ALSA"),
        speaker: ("no output device name contains 'nonexistent'", "fakespeaker (ALSA"),
    }
    for node, (problem, listed) in expected.items():
        assert node.wait() == 2, node.output()
        out = node.output()
        assert "Traceback" not in out, out
        errors = [line for line in out.splitlines() if "[ERROR]" in line]
        assert len(errors) == 1 and "parameter 'device' = 'nonexistent'" in errors[0], out
        assert problem in errors[0], out
        assert listed in out and "Choose one by its index" in out, out
    assert "dry_run:=true" in speaker.output()


# --------------------------------------------------------------------------- loudspeaker


class PacedReader:
    """Reads a FIFO at ``bytes_per_s`` in a thread, like a sound card consuming samples."""

    def __init__(self, fifo: Path, bytes_per_s: float) -> None:
        self.fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # no writer needed yet
        self.bytes_per_s = bytes_per_s
        self.data = bytearray()
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        start, taken = time.monotonic(), 0
        while not self._stop.is_set():
            allowed = int((time.monotonic() - start) * self.bytes_per_s) - taken
            try:
                chunk = os.read(self.fd, min(allowed, 1 << 16)) if allowed > 0 else b""
            except BlockingIOError:
                chunk = b""
            if not chunk:  # not yet allowed, no data, or no writer (yet): the pace of a card
                self._stop.wait(0.005)
                continue
            taken += len(chunk)
            with self.lock:
                self.data.extend(chunk)

    def samples(self, channels: int) -> np.ndarray:
        """What was played so far: float32 frames of the first channel."""
        with self.lock:
            raw = bytes(self.data[: len(self.data) // (4 * channels) * 4 * channels])
        return np.frombuffer(raw, "<f4").reshape(-1, channels)[:, 0]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        os.close(self.fd)


def test_speaker_node_plays_the_chirp_on_true_only_and_publishes_when_it_started(
    tmp_path: Path, spawn: Callable[..., NodeProcess], probe: Live
) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    out = alsa.speaker("fakespeaker")
    alsa.write(default_playback="fakespeaker")
    os.mkfifo(out)  # the device writes into the FIFO; the reader paces it
    started = probe.record("speaker_started", Time)
    vocalize = probe.probe.talk("vocalize_step", Int64MultiArray)
    reader = PacedReader(out, bytes_per_s=4 * 48000 * 4)  # a few times real time
    try:
        speaker = spawn("speaker_node", {"dry_run": False, "device": "speaker"}, alsa.env())
        probe.wait_for(lambda: vocalize.get_subscription_count() == 1, "speaker_node", speaker)
        probe.wait_for(
            lambda: re.search(r"at (\d+) Hz, (\d+) channel", speaker.output()) is not None,
            "the speaker's stream",
            speaker,
        )
        match = re.search(r"at (\d+) Hz, (\d+) channel", speaker.output())
        rate, channels = int(match[1]), int(match[2])
        # the decisions of one controller on steps 1, 2, 3 (in order): only step 2 plays
        decide = [decision_message(StepDecision(7, step, u, 5))
                  for step, u in ((1, False), (2, True), (3, False))]  # fmt: skip
        vocalize.publish(decide[0])
        commanded_ns = time.time_ns()
        vocalize.publish(decide[1])
        vocalize.publish(decide[2])
        probe.wait_for(lambda: len(started) == 1, "speaker_started", speaker)

        def chirp_through() -> bool:
            loud = np.flatnonzero(reader.samples(channels))
            return loud.size > 0 and reader.samples(channels).size - loud[-1] > 0.3 * rate

        probe.wait_for(chirp_through, "the chirp on the device", speaker)
        probe.wait_for(
            lambda: any(s.get("played") == "1" for s in probe.statuses("/speaker_node")),
            "the speaker's diagnostics",
            speaker,
        )
        # nothing else comes in the next 0.3 s of what the device plays (silence)
        heard = reader.samples(channels).size
        probe.wait_for(lambda: reader.samples(channels).size >= heard + 0.3 * rate,
                       "0.3 s more from the device", speaker)  # fmt: skip
        played = reader.samples(channels)
        status = next(s for s in probe.statuses("/speaker_node") if s.get("played") == "1")
        speaker.stop()
    finally:
        reader.close()
    assert speaker.process.returncode == 0, speaker.output()
    assert "Traceback" not in speaker.output() and "[ERROR]" not in speaker.output()

    loud = np.flatnonzero(played)
    chirp = (0.5 * synthesize_chirp(rate, 0.2, amplitude=1.0)).astype(np.float32)
    start = loud[0] - 1  # the chirp's first sample is sin(0) = 0
    assert np.array_equal(played[start : start + chirp.size], chirp)  # exactly the chirp
    assert loud[-1] < start + chirp.size  # once: neither 'false' played anything
    assert (loud[-1] - loud[0] + 2) / rate == pytest.approx(0.2, abs=1e-3)
    spectrum = np.abs(np.fft.rfft(played[start : start + chirp.size]))
    assert 800 <= np.argmax(spectrum) * rate / chirp.size <= 2400  # the chirp's band
    assert status["device"] == "fakespeaker" and status["state"] == "connected"
    assert status["requests"] == "1" and status["errors"] == "0" and status["_level"] == OK
    # From the command to the sound's start, as estimated from PortAudio's output time:
    # the estimate may lie a millisecond early.
    assert float(status["start_delay_s"]) >= -0.005
    (stamp, received_ns) = started[0]
    started_ns = stamp.sec * 10**9 + stamp.nanosec
    assert commanded_ns - 50_000_000 <= started_ns <= received_ns + 1_000_000_000
