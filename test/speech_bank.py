"""espeak-ng's speech bank rendered once per test run, shared by the pytest-xdist workers.

:func:`infomax_contingency.sim.tts.tts_bank` renders every voice of the bank with
espeak-ng (72 processes) and resamples it: about 1 s of CPU, cached per process. Every
worker that builds a room with speech paid it again. Here the first worker to need the
bank at a rate renders it (the package's own function, holding a lock the others wait on)
and saves it under the run's shared temporary directory; the others load the same samples
(``.npy``: float64, exact). Nothing is kept between runs. The children's bank of the
playroom (:func:`~infomax_contingency.sim.tts.children_bank`) is shared the same way.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.sim import tts

Bank = tuple[NDArray[np.float64], ...]


def shared_tts_bank(directory: Path, render: Callable[[int], Bank]) -> Callable[[int], Bank]:
    """A stand-in for ``tts_bank``: ``render(rate)`` once per run, loaded from ``directory``."""
    loaded: dict[int, Bank] = {}

    def bank(rate: int) -> Bank:
        if rate in loaded:
            return loaded[rate]
        files = directory / f"tts_bank_{rate}"
        done = files / "done"
        directory.mkdir(parents=True, exist_ok=True)
        with (directory / f"tts_bank_{rate}.lock").open("w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not done.is_file():
                voices = render(rate)  # raises TtsUnavailableError without espeak-ng
                files.mkdir(exist_ok=True)
                for index, voice in enumerate(voices):
                    np.save(files / f"{index}.npy", voice)
                done.write_text(str(len(voices)))
        voices = tuple(np.load(files / f"{index}.npy") for index in range(int(done.read_text())))
        for voice in voices:
            voice.setflags(write=False)  # read-only, as tts_bank's
        loaded[rate] = voices
        return voices

    return bank


def install(base_temp: Path) -> None:
    """Make ``tts.tts_bank`` and ``tts.children_bank`` the run's shared banks.

    Rooms look them up at each use.
    """
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base_temp = base_temp.parent  # shared by the workers of this run
    tts.tts_bank = shared_tts_bank(base_temp / "tts_bank", tts.tts_bank)
    tts.children_bank = shared_tts_bank(base_temp / "children_bank", tts.children_bank)
