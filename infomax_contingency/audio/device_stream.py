"""What a live device stream is, for the microphone and the loudspeaker alike.

:class:`DeviceStream` owns one PortAudio stream: it opens it (``start``), closes it
(``close``, also as a context manager), notes when it dies (:meth:`DeviceStream._lose`) and
reopens it with back-off (:meth:`DeviceStream._try_reopen`: the first attempt
``backoff_s[0]`` seconds after the loss, each failure doubling the wait up to
``backoff_s[1]``; PortAudio rescans the devices first when no other stream of the audio
modules is open in the process, since a rescan would close those too). A subclass
(:class:`~infomax_contingency.audio.capture.MicrophoneStream`,
:class:`~infomax_contingency.audio.playback.SpeakerOutput`) says how it opens
(:meth:`DeviceStream._open`, which calls :meth:`DeviceStream._start_stream`) and what its
callback does with a block.

Threads: the PortAudio callback runs on PortAudio's thread; every stream opened gets a new
*generation*, and a callback of an older generation (a stream being closed) does nothing.
Times are on ``clock`` (``time.monotonic`` unless given).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from infomax_contingency.audio.common import AudioError, check_positive
from infomax_contingency.audio.devices import (
    CLOSE_WAIT_S,
    CLOSED,
    CONNECTED,
    DISCONNECTED,
    AudioBackend,
    DeviceInfo,
    LogFunction,
    backend_or_default,
    close_stream,
    default_log,
    open_and_start,
    other_streams_open,
    register_stream,
    unregister_stream,
)

Clock = Callable[[], float]
"""Monotonic seconds now."""
Sleep = Callable[[float], None]
"""Wait this many seconds (on the matching clock)."""


def check_backoff(backoff_s: tuple[float, float]) -> tuple[float, float]:
    """``(first, longest)`` reopening waits, seconds, both > 0 and first <= longest."""
    low, high = (check_positive(b, "backoff_s") for b in backoff_s)
    if high < low:
        raise AudioError(f"backoff_s must be (first, longest) with first <= longest: {backoff_s}")
    return low, high


class DeviceStream:
    """One PortAudio stream that is opened, lost and reopened (see the module docstring).

    Args:
        device: device spec (see :func:`~infomax_contingency.audio.devices.resolve_device`).
        backoff_s: first and longest wait between reopening attempts, seconds.
        log: ``log(level, message)`` for state changes (default: the logging module).
        backend: PortAudio access (default: sounddevice).
        clock: monotonic seconds now.
        sleep: ``sleep(seconds)`` for every wait; None: wait on queues and ``time.sleep``.
    """

    kind = "stream"
    """What the stream is, for messages (``microphone``, ``speaker``)."""

    def __init__(
        self,
        device: int | str | None,
        backoff_s: tuple[float, float],
        log: LogFunction | None = None,
        backend: AudioBackend | None = None,
        clock: Clock = time.monotonic,
        sleep: Sleep | None = None,
    ) -> None:
        self.spec = device
        self.backoff_s = check_backoff(backoff_s)
        self._log = log or default_log
        self._backend_arg = backend
        self._backend: AudioBackend | None = None
        self._clock = clock
        self._sleep = sleep
        self._lock = threading.Lock()
        self._stream: Any = None
        self._state = CLOSED
        self._device: DeviceInfo | None = None
        self._offset = 0.0  # clock() - stream clock
        self._generation = 0
        self._finished = False
        self._closers: list[threading.Thread] = []
        self._backoff = self.backoff_s[0]
        self._next_attempt = 0.0
        self._last_error = ""

    # ------------------------------------------------------------------ life cycle

    def start(self) -> Any:
        """Open and start the device; returns the stream object itself.

        Raises:
            AudioDeviceError: the device is missing (the message lists the devices),
                opens with no usable format, or PortAudio is not installed.
        """
        if self._state != CLOSED:
            raise AudioError(f"the {self.kind} is already started")
        self._backend = backend_or_default(self._backend_arg)
        self._open()
        return self

    def close(self) -> None:
        """Stop the stream and release the device (safe to call twice)."""
        self._drop_stream(CLOSED)

    def __enter__(self) -> Any:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def device(self) -> DeviceInfo | None:
        """The device in use (None before :meth:`start`)."""
        return self._device

    @property
    def state(self) -> str:
        """``"connected"``, ``"disconnected"`` or ``"closed"``."""
        return self._state

    # ------------------------------------------------------------------ for subclasses

    def _open(self) -> None:
        """Resolve the device, pick a format and :meth:`_start_stream` (raises on failure)."""
        raise NotImplementedError

    def _start_stream(
        self,
        direction: str,
        device: DeviceInfo,
        rate: int,
        channels: int,
        blocksize: int,
        on_block: Callable[..., None],
    ) -> int:
        """Open and start a stream whose callback is ``on_block(generation, data, ...)``.

        Returns the stream's generation. A callback of an older generation is the
        subclass's to ignore (``on_block`` gets the generation it was opened with).
        """
        with self._lock:
            self._generation += 1
            generation = self._generation
            self._finished = False

        def callback(data: Any, frames: int, time_info: Any, status: Any) -> None:
            on_block(generation, data, frames, time_info, status)

        def finished() -> None:
            if generation == self._generation:
                self._finished = True

        stream, self._offset = open_and_start(
            self._backend, direction, device, rate, channels, blocksize, callback, finished,
            self._clock,
        )  # fmt: skip
        with self._lock:
            self._stream = stream
            self._device = device
            self._state = CONNECTED
        register_stream(self)
        return generation

    def _stream_stopped(self) -> bool:
        """True if the stream is gone, finished or inactive (a device unplugged)."""
        stream = self._stream
        return stream is None or self._finished or not stream.active

    def _drop_stream(self, state: str) -> threading.Thread | None:
        """Close the stream (if any) and enter ``state``; the closer if it is still busy."""
        with self._lock:
            self._state = state
            self._generation += 1
            stream, self._stream = self._stream, None
        unregister_stream(self)
        if stream is None:
            return None
        return close_stream(stream, wait_s=CLOSE_WAIT_S)

    def _lose(self, reason: str, wait_first: bool = True) -> None:
        """The stream died (``reason``): close it, disconnected; the first retry is scheduled.

        ``wait_first``: the first reopening waits ``backoff_s[0]``; else it may come at once.
        """
        closer = self._drop_stream(DISCONNECTED)
        if closer is not None:
            self._closers.append(closer)
        self._last_error = reason
        self._backoff = self.backoff_s[0]
        self._next_attempt = self._clock() + (self._backoff if wait_first else 0.0)

    def _retry_due(self) -> bool:
        """True when the back-off allows the next reopening attempt."""
        return self._clock() >= self._next_attempt

    def _try_reopen(self) -> Exception | None:
        """Reopen the device now (rescanning first if safe); the failure, or None.

        A failure doubles the wait before the next attempt, up to ``backoff_s[1]``.
        """
        self._closers = [t for t in self._closers if t.is_alive()]
        try:
            if not self._closers and not other_streams_open(self):
                self._backend.rescan()
            self._open()
        except Exception as exc:  # noqa: BLE001 - any failure: wait longer and try again
            self._backoff = min(2.0 * self._backoff, self.backoff_s[1])
            self._next_attempt = self._clock() + self._backoff
            return exc
        return None
