"""Errors that the command lines and nodes report as one line, never as a traceback."""

from __future__ import annotations


class MissingPackageError(OSError):
    """An optional Python package that a feature needs is not installed.

    Raised where the feature is asked for (never at start-up of a command that does not
    use it), with one line naming the feature, the package and how to install it. An
    OSError, so every place that reports :data:`USER_ERRORS` reports it as one line.
    """

    def __init__(self, package: str, feature: str, rosdep_key: str = "") -> None:
        key = f"; rosdep key {rosdep_key}" if rosdep_key else ""
        super().__init__(
            f"{feature} needs the Python package '{package}', which is not installed:"
            f" pip install {package}{key}"
        )
        self.package = package


USER_ERRORS = (ValueError, OSError)
"""Errors that end a command or a node with one line and exit status 2: bad parameters
(``ConfigError``, ``ParameterError``), tables (``PolicyTableError``), audio
(``AudioError``) — all ValueErrors — unreadable files and missing optional packages
(:class:`MissingPackageError`)."""
