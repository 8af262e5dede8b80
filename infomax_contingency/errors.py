"""Errors that the command lines and nodes report as one line, never as a traceback."""

USER_ERRORS = (ValueError, OSError)
"""Errors that end a command or a node with one line and exit status 2: bad parameters
(``ConfigError``, ``ParameterError``), tables (``PolicyTableError``), audio
(``AudioError``) — all ValueErrors — and unreadable files."""
