"""The nodes' console scripts: a stop signal while a node is still starting ends it quietly.

A node's module loads rclpy, numpy and the core before its ``main()`` takes over SIGINT
and SIGTERM (:class:`~infomax_contingency.nodes.runtime.StopSignals`): 0.3 s on a quiet
machine, seconds on a loaded one. A launch that stops in that time (another node refused
its parameters) used to get a KeyboardInterrupt traceback from each node still loading.
These entry points catch both signals from their first line: such a node exits with
status 0 and says nothing, as a node stopped later does. A node whose module needs an
optional package that is not installed (recorder_node without ``rosbags``) ends with
one ERROR line naming the package, status 2, as a node refusing its parameters does.

They also start each node with one BLAS thread (:func:`use_one_blas_thread`).

``python -m infomax_contingency.nodes.entry NODE ARGS...`` runs ``NODE`` the same way (the
test harness and the demo start their node processes so).
"""

from __future__ import annotations

import functools
import importlib
import os
import signal
import sys
from collections.abc import MutableMapping
from typing import Any

from infomax_contingency.errors import MissingPackageError
from infomax_contingency.lifetime import note_stop_while_starting, stop_came_while_starting

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

NODES = (
    "mic_node",
    "controller_node",
    "belief_node",
    "posture_node",
    "fake_audio_node",
    "speaker_node",
    "recorder_node",
)
"""The node executables (module names under ``infomax_contingency.nodes``)."""

NODE_MODULES = (*NODES, "bringup")
"""Every executable under ``infomax_contingency.nodes`` that these entry points run."""


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
"""What numpy's OpenBLAS reads, once, when numpy is first imported: its thread count."""


def use_one_blas_thread(environ: MutableMapping[str, str] = os.environ) -> None:
    """Give numpy's OpenBLAS one thread, unless the user chose a count in ``environ``.

    By default OpenBLAS starts a thread per core in every process that imports numpy.
    The nodes compute no matrix products (their arrays hold a few hundred numbers per
    step), so those threads only cost start-up: importing a node's module took 0.35 s of
    CPU with them and 0.20 s with one thread (docs/ENVIRONMENT.md), for each of the six
    processes of a graph. Takes effect only before numpy is first imported; child
    processes inherit it.
    """
    if not any(environ.get(name, "").strip() for name in BLAS_THREAD_VARIABLES):
        environ["OPENBLAS_NUM_THREADS"] = "1"


def _stopped_while_starting(signum: int, frame: Any) -> None:
    note_stop_while_starting()
    # The process ends: a second stop signal (the terminal's Ctrl-C and ros2 launch's
    # both reach a node) must not raise a KeyboardInterrupt on the way out.
    for stop_signal in STOP_SIGNALS:
        signal.signal(stop_signal, signal.SIG_IGN)
    raise SystemExit(0)


def _quiet_about_a_lost_stop(unraisable: Any, report: Any = sys.__unraisablehook__) -> None:
    """``sys.unraisablehook`` while :func:`run_module` runs: a lost stop's exit is not news.

    Only a ``SystemExit`` after a stop signal came while starting is kept quiet; everything
    else goes to ``report`` (the hook before).
    """
    if stop_came_while_starting() and unraisable.exc_type is SystemExit:
        return
    report(unraisable)


def run_module(module: str) -> int:
    """Import ``module`` and return what its ``main()`` returns (the exit status).

    A stop signal before ``main()`` takes the signals over raises ``SystemExit(0)``; so
    does one that arrived while the process started with the signals blocked (a launcher
    may block them across ``exec``: they wait until this function unblocks them), and one
    whose ``SystemExit`` was lost while the module loaded: Python cannot raise from a
    weakref callback or a ``__del__``, which importlib runs, and only reports it
    (:func:`~infomax_contingency.lifetime.stop_came_while_starting`; ``StopSignals.install``
    takes such a stop as requested if ``main()`` has already begun).
    Afterwards each signal goes back to its previous handler, unless ``main()`` left it
    with another one: a node that ends ignores both (``StopSignals.ignore_from_now_on``),
    so a second Ctrl-C while the interpreter shuts down raises nothing. A module that
    cannot load for want of an optional package is logged as one ERROR line (status 2).
    """
    previous = {signum: signal.signal(signum, _stopped_while_starting) for signum in STOP_SIGNALS}
    report = sys.unraisablehook
    quiet = sys.unraisablehook = functools.partial(_quiet_about_a_lost_stop, report=report)
    try:
        # contingency.launch.py starts the nodes with both signals blocked, so that a Ctrl-C
        # while the interpreter itself starts (before this line) waits instead of raising a
        # KeyboardInterrupt there; one that came meanwhile is delivered now, to the handler.
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        use_one_blas_thread()
        try:
            main = importlib.import_module(module).main
        except MissingPackageError as error:
            import rclpy.logging

            rclpy.logging.get_logger(module.rsplit(".", 1)[-1]).error(str(error))
            return 2
        if stop_came_while_starting():  # its SystemExit was lost while the module loaded
            raise SystemExit(0)
        return main()
    finally:
        for signum, handler in previous.items():
            if signal.getsignal(signum) is _stopped_while_starting:
                signal.signal(signum, handler)
        if sys.unraisablehook is quiet:  # unless main() put in a hook of its own
            sys.unraisablehook = report
        note_stop_while_starting(False)


def _entry(node: str) -> Any:
    def entry() -> int:
        return run_module(f"infomax_contingency.nodes.{node}")

    entry.__name__ = entry.__qualname__ = node
    entry.__doc__ = f"The ``{node}`` executable."
    return entry


mic_node = _entry("mic_node")
controller_node = _entry("controller_node")
belief_node = _entry("belief_node")
posture_node = _entry("posture_node")
fake_audio_node = _entry("fake_audio_node")
speaker_node = _entry("speaker_node")
recorder_node = _entry("recorder_node")
bringup = _entry("bringup")


def main(argv: list[str] | None = None) -> int:
    """``python -m infomax_contingency.nodes.entry NODE ARGS...``."""
    argv = list(sys.argv if argv is None else argv)
    if len(argv) < 2 or argv[1] not in NODE_MODULES:
        print(f"usage: python -m infomax_contingency.nodes.entry {{{','.join(NODE_MODULES)}}}"
              " [ARGS...]", file=sys.stderr)  # fmt: skip
        return 2
    sys.argv = [argv[0], *argv[2:]]  # what the node's own parser and rclpy expect
    return run_module(f"infomax_contingency.nodes.{argv[1]}")


if __name__ == "__main__":
    sys.exit(main())
