"""Hermetic virtual ALSA devices for tests of the real sounddevice -> PortAudio -> ALSA path.

Each test writes its own ALSA configuration into a temporary directory and runs the code
under test in a **subprocess** (a scenario of ``child_alsa.py``) with ``ALSA_CONFIG_PATH``
pointing at it: PortAudio reads
the ALSA configuration when it initializes (at ``import sounddevice``), so a fresh process
per configuration is needed, and no user or system configuration is read or touched.

The devices are ALSA ``file`` plugins on a ``null`` slave:

* a **microphone** reads a raw file of float32 little-endian interleaved samples (the
  format PortAudio asks for; the ``null`` slave accepts any format, so the file must hold
  the samples in the format the stream is opened with, and live_audio always opens
  float32), padded with zeros at the end, because at the end of its input the plugin
  repeats the last period forever;
* a **rate-locked microphone** wraps it in a ``plug`` whose slave runs at one rate and
  whose rate converter does not exist: a stream at that rate passes straight through,
  any other rate needs the converter and fails to open, like hardware that only runs at
  48 kHz (PortAudio also reports it as the device's default rate);
* a **FIFO microphone** reads from a named pipe, so a test can pace the audio and stall
  it (a device that stops delivering);
* a **loudspeaker** writes what is played (float32 raw) to a file.

The ``null`` slave has no clock: capture runs hundreds of times faster than real time
and playback returns at once. PortAudio 19.6 aborts at initialization when the
configuration defines no ``default`` PCM, so one is always written.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.audio.wav import read_wav

ROOT = Path(__file__).resolve().parent.parent
CHILD = Path(__file__).resolve().parent / "child_alsa.py"
"""The child process that runs each scenario (see its module docstring)."""


def _q(path: Path) -> str:
    return json.dumps(str(path))  # a double-quoted ALSA string


class VirtualAlsa:
    """A set of virtual devices in ``directory`` and the configuration naming them."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.config = self.directory / "asound.conf"
        self._pcms: dict[str, str] = {}
        self._capture: dict[str, str] = {}
        self._playback: dict[str, str] = {}

    # ------------------------------------------------------------------ devices

    def microphone(
        self,
        name: str,
        samples: np.ndarray,
        *,
        pad_s: float = 2.0,
        rate: int = 16000,
        only_rate: int | None = None,
    ) -> Path:
        """A capture device that plays ``samples`` (frames, or frames x channels, in [-1, 1]).

        Args:
            name: ALSA PCM name (PortAudio lists it under this name).
            samples: what the microphone "hears".
            pad_s: seconds of zeros appended (at ``rate``).
            rate: rate of ``samples``, Hz (only used for the padding length).
            only_rate: if set, the device opens at this rate only.

        Returns:
            the raw file.
        """
        x = np.asarray(samples, dtype=np.float32)
        if x.ndim == 1:
            x = x[:, np.newaxis]
        pad = np.zeros((round(pad_s * rate), x.shape[1]), dtype=np.float32)
        raw = self.directory / f"{name}.in.raw"
        np.concatenate((x, pad)).astype("<f4").tofile(raw)
        self._add_capture(name, raw, only_rate, x.shape[1])
        return raw

    def wav_microphone(self, name: str, wav: Path, **kwargs: object) -> Path:
        """A microphone that plays a WAV file's samples (at the file's own rate)."""
        samples, rate = read_wav(wav)
        return self.microphone(name, samples, rate=rate, **kwargs)

    def fifo_microphone(self, name: str) -> Path:
        """A microphone reading float32 samples from a named pipe (see ``fifos`` of child_alsa)."""
        fifo = self.directory / f"{name}.fifo"
        if not fifo.exists():
            os.mkfifo(fifo)
        self._add_capture(name, fifo, None, 1)
        return fifo

    def _add_capture(self, name: str, infile: Path, only_rate: int | None, channels: int) -> None:
        file_pcm = (
            f'{{ type file; slave.pcm {{ type null }}; file "/dev/null"; infile {_q(infile)};'
            ' format "raw" }'
        )
        if only_rate is not None:
            file_pcm = (
                f"{{ type plug; slave {{ pcm {file_pcm}; rate {only_rate}; format FLOAT_LE;"
                f' channels {channels} }}; rate_converter "no_such_rate_converter" }}'
            )
        # capture only, like a real microphone (a file plugin alone also plays)
        self._capture[name] = f"{{ type asym; capture.pcm {file_pcm} }}"

    def speaker(self, name: str) -> Path:
        """A playback device writing what is played (float32 raw) to a file."""
        out = self.directory / f"{name}.out.raw"
        # playback only, like a real loudspeaker (a file plugin alone also records silence)
        self._playback[name] = (
            f"{{ type asym; playback.pcm {{ type file; slave.pcm {{ type null }}; file {_q(out)};"
            ' format "raw" } }'
        )
        return out

    def remove(self, name: str) -> None:
        """Forget a device (write the configuration again to make it vanish)."""
        self._capture.pop(name, None)
        self._playback.pop(name, None)

    # ------------------------------------------------------------------ configuration

    def write(
        self,
        default_capture: str | None = None,
        default_playback: str | None = None,
        path: Path | None = None,
    ) -> Path:
        """Write the configuration: every device, and ``default`` made of the two named ones.

        Without a default capture (playback) device, ``default`` has no capture (playback)
        side, so PortAudio then sees no default input (output). ``path`` writes elsewhere
        than :attr:`config` (e.g. a variant to swap in later).
        """
        lines = [f"pcm.{n} {pcm}" for n, pcm in {**self._capture, **self._playback}.items()]
        sides = []
        if default_capture is not None:
            sides.append(f"capture.pcm {json.dumps(default_capture)}")
        if default_playback is not None:
            sides.append(f"playback.pcm {json.dumps(default_playback)}")
        if not sides:  # some default is needed; a null playback side offers no input
            sides.append("playback.pcm { type null }")
        lines.append("pcm.!default { type asym; " + "; ".join(sides) + " }")
        path = self.config if path is None else Path(path)
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return path

    def env(self) -> dict[str, str]:
        """The environment of a process that sees only these devices."""
        env = dict(os.environ)
        env["ALSA_CONFIG_PATH"] = str(self.config)
        env.pop("ALSA_CONFIG_DIR", None)
        env["PYTHONUNBUFFERED"] = "1"
        return env

    def run(self, scenario: str, timeout: float = 60.0, **arguments: Any) -> dict:
        """Run ``scenario`` of ``child_alsa.py`` in a fresh process that sees only these devices.

        ``arguments`` (JSON-serialisable) are the scenario's keyword arguments; the
        scenario prints one JSON object on its last line, returned with the process's
        output under ``_stdout`` and ``_stderr``.
        """
        if not self.config.exists():
            self.write()
        proc = subprocess.run(
            [sys.executable, str(CHILD), scenario, json.dumps(arguments)],
            env=self.env(),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        lines = proc.stdout.strip().splitlines()
        if proc.returncode != 0 or not lines:
            raise AssertionError(
                f"subprocess failed (exit {proc.returncode})\nstdout:\n{proc.stdout}\n"
                f"stderr:\n{proc.stderr}"
            )
        result = json.loads(lines[-1])
        result["_stderr"] = proc.stderr
        result["_stdout"] = proc.stdout
        return result


def read_raw(path: Path, channels: int = 1) -> np.ndarray:
    """A float32 raw file written by a virtual loudspeaker, shaped (frames, channels)."""
    return np.fromfile(path, dtype="<f4").reshape(-1, channels)
