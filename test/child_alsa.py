"""Child process of the ALSA tests: one audio scenario on virtual devices, a JSON result.

Run as ``python test/child_alsa.py SCENARIO ARGS_JSON`` by :meth:`VirtualAlsa.run
<alsa_devices.VirtualAlsa.run>`, in an environment whose ``ALSA_CONFIG_PATH`` names the
virtual devices. The last line of the output is one JSON object. A fresh process per
scenario, because PortAudio reads the ALSA configuration once, when it initialises.

``ARGS_JSON`` may hold ``fifos`` (paths of FIFO microphones): they are opened read-write
before anything imports sounddevice, since PortAudio opens every device while it
initialises and opening a FIFO for reading blocks until someone holds it for writing.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

FIFO_FDS: dict[str, int] = {}
"""FIFO path -> a descriptor open for writing the microphone's audio (float32 samples)."""

DEADLINE_S = 30.0
"""Seconds a scenario may wait for windows before it gives up (a guard, not a pace)."""


def _log_into(lines: list[str]) -> Callable[[Any, str], None]:
    return lambda level, message: lines.append(message)


def capture(spec: Any, n: int, window_s: float, channel: Any, channels: Any) -> dict:
    """``n`` windows from the microphone ``spec``: energies (dB), status and log."""
    from infomax_contingency.audio.capture import MicrophoneStream

    logs: list[str] = []
    mic = MicrophoneStream(spec, window_s=window_s, channel=channel, channels=channels,
                           queue_s=60, log=_log_into(logs)).start()  # fmt: skip
    windows: list[Any] = []
    end = time.monotonic() + DEADLINE_S
    while len(windows) < n and time.monotonic() < end:
        windows += mic.read_windows(0.1)
    status = mic.status().as_dict()
    mic.close()
    windows = windows[:n]
    return {
        "energies": [w.energy_db for w in windows],
        "intact": all(w.intact and w.segment == 0 for w in windows),
        "status": status,
        "logs": logs,
    }


def input_rates(device: str) -> dict:
    """Whether ``device`` opens at 16 and 48 kHz, and its default rate (Hz)."""
    import sounddevice as sd

    def opens(rate: int) -> bool:
        try:
            sd.check_input_settings(device, samplerate=rate, channels=1, dtype="float32")
        except Exception:  # noqa: BLE001 - PortAudio's refusal, whatever its type
            return False
        return True

    return {"r16": opens(16000), "r48": opens(48000),
            "default": sd.query_devices(device)["default_samplerate"]}  # fmt: skip


def missing(devices: list[list[Any]]) -> dict:
    """Open each ``[kind, spec]`` (kind ``mic`` or ``speaker``); the error of each."""
    from infomax_contingency.audio.capture import MicrophoneStream
    from infomax_contingency.audio.devices import AudioDeviceError
    from infomax_contingency.audio.playback import SpeakerOutput

    messages = []
    for kind, spec in devices:
        make = MicrophoneStream if kind == "mic" else SpeakerOutput
        try:
            (make() if spec is None else make(spec)).start()
            messages.append("opened")
        except AudioDeviceError as error:
            messages.append(str(error))
    return {"messages": messages}


def _wait(condition: Callable[[], bool], what: str) -> None:
    """Poll ``condition`` until it holds; RuntimeError after :data:`DEADLINE_S`."""
    end = time.monotonic() + DEADLINE_S
    while not condition():
        if time.monotonic() > end:
            raise RuntimeError(f"{what}: not within {DEADLINE_S:g} s")
        time.sleep(0.001)  # polls the callback's counters; the deadline bounds it


def speaker(play: bool) -> dict:
    """Open ``fakespeaker``; play the chirp once if ``play``; its events and status.

    The chirp is asked for once the stream has filled a block of silence (so silence
    precedes it in the device's output), and the speaker is closed once the chirp has
    gone to the device and the callback has filled two blocks after it (each block is
    written to ALSA before the next is asked for).
    """
    from infomax_contingency.audio.playback import SpeakerOutput

    output = SpeakerOutput("fakespeaker", volume=0.5).start()
    events = []
    _wait(lambda: output.blocks_served > 0, "the output stream's first block")
    if play:
        output.play()
        events = [dataclasses.asdict(e) for e in output.events(DEADLINE_S)]
        _wait(output.drained, "the chirp handed to the device")
    blocks = output.blocks_served
    _wait(lambda: output.blocks_served > blocks + 1, "two blocks of silence after it")
    status = output.status().as_dict()
    output.close()
    return {"events": events, "status": status}


def cli(args: list[str]) -> dict:
    """Run ``infomax-contingency ARGS``; its exit status."""
    from infomax_contingency.cli.main import main

    rc = main(args)
    sys.stdout.flush()
    return {"rc": rc}


def _drain(fd: int) -> None:
    """Read a FIFO empty without blocking."""
    os.set_blocking(fd, False)
    try:
        while os.read(fd, 1 << 16):
            pass
    except BlockingIOError:
        pass
    os.set_blocking(fd, True)


def _pipe_bytes(fd: int) -> int:
    """Bytes waiting in a pipe."""
    import fcntl
    import struct
    import termios

    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0" * 4))[0]


def vanish(fifo: str, a: str, b: str, missing_conf: str, full_conf: str, conf: str,
           nb: int) -> dict:  # fmt: skip
    """A FIFO microphone stalls, vanishes from the configuration and comes back.

    Plays ``a`` (a .npy of float32 samples), waits until the stream reports the stall,
    swaps in ``missing_conf``; once a rescan failed to find the device, queues ``b`` and
    swaps ``full_conf`` back in. Returns every window (segment, energy dB, gap s).
    """
    import fcntl

    import numpy as np

    from infomax_contingency.audio.capture import MicrophoneStream

    ZEROS = np.zeros(16000, "<f4")  # noqa: N806 - a constant of the scenario
    fd = FIFO_FDS[fifo]
    fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, 1 << 20)  # room for a whole part: no short reads
    logs: list[str] = []
    mic = MicrophoneStream("fifomic", window_s=0.25, stall_timeout_s=0.5, backoff_s=(0.2, 0.8),
                           queue_s=30, log=_log_into(logs))  # fmt: skip
    os.write(fd, np.load(a).tobytes())
    mic.start()
    stop = threading.Event()

    def director() -> None:
        phase = "A"
        while phase != "B" and not stop.wait(0.01):  # polls the status, paces nothing
            status = mic.status()
            if phase == "A" and status.state == "disconnected":
                with open(missing_conf, "rb") as source, open(conf, "wb") as target:
                    target.write(source.read())  # the device vanishes
                # The stalled stream is being closed; its blocked reads return once the
                # FIFO has data, and what they return belongs to no window.
                os.write(fd, ZEROS.tobytes())
                phase = "gone"
                continue  # the status above is from before the device vanished
            if phase == "gone" and _pipe_bytes(fd) < ZEROS.nbytes:
                # A read of the closing stream that came back for more would block its
                # close, and no rescan comes while a close hangs: keep the reads fed.
                os.write(fd, ZEROS.tobytes())
            if phase == "gone" and "contains 'fifomic'" in status.last_error:
                # a rescan ran, so the old stream is closed: empty the pipe, queue what
                # the device will say when it is back, and bring it back
                _drain(fd)
                os.write(fd, np.load(b).tobytes())
                with open(full_conf, "rb") as source, open(conf, "wb") as target:
                    target.write(source.read())
                phase = "B"

    thread = threading.Thread(target=director, daemon=True)
    thread.start()
    windows: list[Any] = []
    end = time.monotonic() + 40
    while sum(w.segment == 1 for w in windows) < nb and time.monotonic() < end:
        windows += mic.read_windows(0.05)
    stop.set()
    thread.join(timeout=5.0)
    status = mic.status().as_dict()
    os.close(fd)  # no writer left: reads return at once, so the stream closes
    mic.close()
    return {"windows": [[w.segment, w.energy_db, w.gap_s] for w in windows],
            "status": status, "logs": logs}  # fmt: skip


SCENARIOS: dict[str, Callable[..., dict]] = {
    "capture": capture,
    "input_rates": input_rates,
    "missing": missing,
    "speaker": speaker,
    "cli": cli,
    "vanish": vanish,
}


def main(argv: list[str]) -> int:
    """Run ``argv[0]`` with the keyword arguments in ``argv[1]`` (JSON); print the result."""
    if len(argv) != 2 or argv[0] not in SCENARIOS:
        print(f"usage: child_alsa.py {{{','.join(SCENARIOS)}}} ARGS_JSON", file=sys.stderr)
        return 2
    kwargs = json.loads(argv[1])
    for path in kwargs.pop("fifos", []):
        FIFO_FDS[path] = os.open(path, os.O_RDWR)
    result = SCENARIOS[argv[0]](**kwargs)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
