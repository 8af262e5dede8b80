"""The robot's loudspeaker: one sound played on command, without blocking, with its DAC start.

An output stream runs continuously and plays silence; :meth:`SpeakerOutput.play` asks
the PortAudio callback to start the sound at its next block, and a :class:`PlayEvent`
reports when it really started (DAC time on the speaker's clock). Commands never queue
up (overlap policy ``restart`` or ``skip``).

Wiring in a node::

    speaker = SpeakerOutput(device, sound=wav_or_none, volume=volume, log=log).start()
    speaker.play()                           # on vocalize: true; never blocks
    for event in speaker.events():           # in a timer: when each sound really started
        publish(event.start_time)
"""

from __future__ import annotations

import dataclasses
import queue
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.common import AudioError, check_positive
from infomax_contingency.audio.device_stream import DeviceStream
from infomax_contingency.audio.devices import (
    CLOSED,
    CONNECTED,
    OUTPUT,
    AudioBackend,
    LogFunction,
    negotiate_format,
    resolve_device,
)
from infomax_contingency.audio.resample import check_resampling, resample
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.audio.wav import open_wav_info, read_wav, to_mono

OVERLAP_POLICIES = ("restart", "skip")


@dataclasses.dataclass(frozen=True)
class PlayEvent:
    """A sound that started playing.

    Attributes:
        sequence: the number :meth:`SpeakerOutput.play` returned for the command.
        requested_time: when ``play()`` was called, speaker-clock seconds.
        start_time: DAC time of the sound's first sample, speaker-clock seconds; never
            before the callback that filled its block ran (see :meth:`SpeakerOutput._on_block`).
        duration_s: length of the sound, seconds.
        interrupted: True if it cut short a sound that was still playing.
    """

    sequence: int
    requested_time: float
    start_time: float
    duration_s: float
    interrupted: bool


@dataclasses.dataclass(frozen=True)
class SpeakerStatus:
    """Counters and state of a :class:`SpeakerOutput`, for diagnostics.

    Attributes:
        state: ``"connected"``, ``"disconnected"`` (reopened on the next play) or ``"closed"``.
        device: name of the device in use (or last used).
        device_index: its PortAudio index.
        device_rate: rate the device is opened at, Hz.
        channels: channels opened (the sound goes to all of them).
        requests: play commands.
        played: sounds started.
        interrupted: sounds cut short by a newer command (policy ``restart``).
        skipped: commands ignored because a sound was playing (policy ``skip``).
        underflows: PortAudio output underflows.
        errors: failed plays and stream failures.
        lost_events: start reports dropped because nobody read them.
        last_error: the latest problem, "" if none.
    """

    state: str
    device: str
    device_index: int | None
    device_rate: int
    channels: int
    requests: int
    played: int
    interrupted: int
    skipped: int
    underflows: int
    errors: int
    lost_events: int
    last_error: str

    def as_dict(self) -> dict[str, Any]:
        """The fields as a dict (e.g. for diagnostic key/values)."""
        return dataclasses.asdict(self)


def load_sound(path: str | Path, rate: int) -> NDArray[np.float64]:
    """A WAV file as mono float64 samples at ``rate`` Hz (channels averaged).

    A rate whose filter is too long is refused before the samples are read.
    """
    check_resampling(open_wav_info(path).rate, rate, str(path))
    samples, file_rate = read_wav(path)
    return resample(to_mono(samples), file_rate, rate)


class SpeakerOutput(DeviceStream):
    """The robot's loudspeaker: plays one sound on command, without blocking.

    An output stream runs continuously and plays silence; :meth:`play` asks the callback
    to start the sound at the beginning of its next block. Commands never queue up: a
    command that arrives while the sound is still playing restarts it from the beginning
    (policy ``"restart"``, the default: the sound then always starts at the latest
    command, as the model's timer assumes) or is ignored (``"skip"``). Several commands
    before the next block count as one.

    For every sound started, a :class:`PlayEvent` with the DAC time of its first sample
    is queued for :meth:`events`. If the stream dies (device unplugged), the next
    :meth:`play` reopens it (at most once per ``retry_s``).

    Args:
        device: output device spec (see :func:`resolve_device`).
        sound: the sound: None for the robot's chirp
            (:func:`~infomax_contingency.audio.synth.synthesize_chirp`, ``duration_s``, made at
            the device rate), a WAV file path, or mono samples at ``sound_rate``.
        sound_rate: rate of ``sound`` samples, Hz (only for arrays).
        duration_s: chirp length, seconds (only for the default sound).
        volume: gain applied to the sound, 0..1.
        overlap: ``"restart"`` or ``"skip"`` (see above).
        rate: device rate to try first, Hz (default: the device's own rate).
        block_s: PortAudio block length, seconds (the start granularity).
        retry_s: least time between reopening attempts after a failure, seconds.
        log: ``log(level, message)`` (default: the logging module).
        backend: PortAudio access (default: sounddevice).
        clock: monotonic seconds now (default ``time.monotonic``): request times, DAC
            times and the ``retry_s`` limit are on it.
        sleep: ``sleep(seconds)`` for :meth:`events`' wait (then the queue is polled);
            default None: wait on the queue.
    """

    kind = "speaker"

    def __init__(
        self,
        device: int | str | None = None,
        sound: str | Path | ArrayLike | None = None,
        sound_rate: int | None = None,
        duration_s: float = 0.2,
        volume: float = 1.0,
        overlap: str = "restart",
        rate: int | None = None,
        block_s: float = 0.01,
        retry_s: float = 2.0,
        log: LogFunction | None = None,
        backend: AudioBackend | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        if overlap not in OVERLAP_POLICIES:
            raise AudioError(
                f"overlap must be one of {', '.join(OVERLAP_POLICIES)}, got {overlap!r}"
            )
        if sound is not None and not isinstance(sound, str | Path) and sound_rate is None:
            raise AudioError("sound samples need their sound_rate (Hz)")
        super().__init__(device, (retry_s, retry_s), log, backend, clock, sleep)
        self.overlap = overlap
        self._sound_arg = sound
        self._sound_rate = sound_rate
        self.duration_s = check_positive(duration_s, "duration_s")
        self._volume = self._check_volume(volume)
        self._rate_arg = rate
        self.block_s = check_positive(block_s, "block_s")
        self.retry_s = check_positive(retry_s, "retry_s")
        self._device_rate = 0
        self._channels = 0
        self._events: queue.Queue[PlayEvent] = queue.Queue(maxsize=256)
        self._source: NDArray[np.float64] = np.empty(0)
        self._sound: NDArray[np.float32] = np.empty(0, np.float32)
        # command handoff: play() bumps _requested (after setting _request_time); the
        # callback serves the latest request it has not served
        self._requested = 0
        self._request_time = 0.0
        self._served = 0
        self._pos = -1  # sample of the sound to play next; -1 = silent
        self._blocks_served = 0
        self._requests = 0
        self._played = 0
        self._interrupted = 0
        self._skipped = 0
        self._underflows = 0
        self._errors = 0
        self._lost_events = 0

    @staticmethod
    def _check_volume(volume: float) -> float:
        if isinstance(volume, bool) or not isinstance(volume, int | float):
            raise AudioError(f"volume must be a number in [0, 1], got {volume!r}")
        if not 0.0 <= volume <= 1.0:
            raise AudioError(f"volume must lie in [0, 1], got {volume!r}")
        return float(volume)

    # ------------------------------------------------------------------ life cycle

    def close(self) -> None:
        """Stop the stream and release the device (safe to call twice).

        A sound still playing is cut, and so are the blocks still in the device's buffer
        (PortAudio's close aborts: draining a dead or shared ALSA device can block). To
        let a sound end first, wait until :meth:`drained`, then for a block or two more.
        """
        self._pos = -1
        super().close()

    @property
    def device_rate(self) -> int:
        """Rate the device is opened at, Hz (0 before :meth:`start`)."""
        return self._device_rate

    @property
    def sound(self) -> NDArray[np.float64]:
        """The sound at the device rate, before the volume gain."""
        return self._source

    @property
    def volume(self) -> float:
        """Gain applied to the sound, 0..1."""
        return self._volume

    @volume.setter
    def volume(self, value: float) -> None:
        self._volume = self._check_volume(value)
        self._sound = (self._source * self._volume).astype(np.float32)

    @property
    def blocks_served(self) -> int:
        """Blocks the PortAudio callback has filled (sound or silence) since :meth:`start`."""
        return self._blocks_served

    def drained(self) -> bool:
        """True when every command so far has been served and its sound handed to the device.

        The last blocks may still be in the device's buffer (:attr:`blocks_served` tells
        when the callback has filled more after them).
        """
        return self._served == self._requested and self._pos < 0

    def status(self) -> SpeakerStatus:
        """A snapshot of the counters."""
        d = self._device
        return SpeakerStatus(
            state=self._state,
            device=d.name if d else "",
            device_index=d.index if d else None,
            device_rate=self._device_rate,
            channels=self._channels,
            requests=self._requests,
            played=self._played,
            interrupted=self._interrupted,
            skipped=self._skipped,
            underflows=self._underflows,
            errors=self._errors,
            lost_events=self._lost_events,
            last_error=self._last_error,
        )

    def _make_sound(self, rate: int) -> NDArray[np.float64]:
        if self._sound_arg is None:
            return synthesize_chirp(rate, self.duration_s, amplitude=1.0)
        if isinstance(self._sound_arg, str | Path):
            return load_sound(self._sound_arg, rate)
        samples = to_mono(np.asarray(self._sound_arg, dtype=np.float64))
        return resample(samples, self._sound_rate, rate)

    def _open(self) -> None:
        backend = self._backend
        device = resolve_device(self.spec, OUTPUT, backend)
        rate, channels, _ = negotiate_format(device, OUTPUT, self._rate_arg, 1, backend)
        source = self._make_sound(rate)
        if source.size == 0:
            raise AudioError("the robot's sound is empty")
        blocksize = max(1, round(self.block_s * rate))
        self._source = source
        self._sound = (source * self._volume).astype(np.float32)
        self._pos = -1
        self._served = self._requested
        self._device_rate = rate
        self._start_stream(OUTPUT, device, rate, channels, blocksize, self._on_block)
        self._channels = channels
        self._log(
            "info",
            f"speaker: {device.describe(OUTPUT)} at {rate} Hz, {channels} channel(s);"
            f" sound {source.size / rate:.3f} s, volume {self._volume:g}",
        )

    # ------------------------------------------------------------------ playing

    def play(self) -> int | None:
        """Start the sound at the beginning of the next block, without waiting.

        Returns:
            The command's sequence number (see :class:`PlayEvent`), or None if the device
            is unavailable (the error is counted; a later call retries).
        """
        if self._state == CLOSED:
            raise AudioError("the speaker is not started (or already closed)")
        self._requests += 1
        if not self._healthy():
            return None
        self._request_time = self._clock()
        self._requested += 1
        return self._requested

    def _healthy(self) -> bool:
        """True if the stream runs; otherwise try to reopen it (rate-limited)."""
        if not self._stream_stopped():
            return True
        if self._state == CONNECTED:
            self._errors += 1
            self._pos = -1  # a sound cut by a dead stream is not resumed on the next one
            self._lose("the output stream stopped (device unplugged?)", wait_first=False)
            self._log("warning", f"speaker: {self._last_error}")
        if not self._retry_due():
            self._errors += 1
            return False
        failure = self._try_reopen()
        if failure is not None:
            self._errors += 1
            self._last_error = f"cannot reopen the speaker: {failure}"
            self._log("warning", self._last_error)
            return False
        return True

    def events(self, timeout: float = 0.0) -> list[PlayEvent]:
        """Sounds started since the last call; waits up to ``timeout`` s for the first."""
        out: list[PlayEvent] = []
        try:
            if timeout > 0 and self._sleep is None:
                out.append(self._events.get(timeout=timeout))
            elif timeout > 0 and self._events.empty():
                self._sleep(timeout)
            while True:
                out.append(self._events.get_nowait())
        except queue.Empty:
            pass
        return out

    def _on_block(
        self, generation: int, outdata: np.ndarray, frames: int, time_info: Any, status: Any
    ) -> None:
        """PortAudio callback: copy the next part of the sound (or silence) into the block."""
        self._blocks_served += 1
        if status.output_underflow:
            self._underflows += 1
        requested = self._requested
        if requested != self._served and generation == self._generation:
            self._served = requested
            playing = self._pos >= 0
            if playing and self.overlap == "skip":
                self._skipped += 1
            else:
                if playing:
                    self._interrupted += 1
                self._pos = 0
                self._played += 1
                # A block filled now cannot play before now. PortAudio's DAC time comes
                # from the device's last status time stamp, which can be stale: on a
                # loaded machine it was 13 ms before the command that this block answers.
                now = self._clock()
                t = time_info.outputBufferDacTime or time_info.currentTime
                start = max(t + self._offset, now) if t else now
                event = PlayEvent(
                    requested,
                    self._request_time,
                    start,
                    self._sound.size / self._device_rate,
                    playing,
                )
                try:
                    self._events.put_nowait(event)
                except queue.Full:
                    self._lost_events += 1
        if self._pos < 0:
            outdata.fill(0)
            return
        sound = self._sound
        n = min(frames, sound.size - self._pos)
        outdata[:n] = sound[self._pos : self._pos + n, np.newaxis]
        outdata[n:] = 0
        self._pos += n
        if self._pos >= sound.size:
            self._pos = -1
