"""Error types. Every error a user can cause is an ``InputError`` whose message
names the file (and record) at fault; the command line prints it as one line
and exits with status 2."""

from __future__ import annotations


class SeglocError(Exception):
    """Base class of segloc's own errors."""


class InputError(SeglocError):
    """Bad input: a missing or malformed file, an empty map, an unmatched survey."""

    def __init__(self, message: str, path: object | None = None, row: int | None = None):
        where = ""
        if path is not None:
            where = f"{path}"
            if row is not None:
                where += f", row {row}"
            where += ": "
        super().__init__(where + message)
        self.path = path
        self.row = row


class Interrupted(Exception):
    """Ctrl-C, SIGTERM or SIGHUP during a command: its ``KeyboardInterrupt``, taken from click
    (which would print an empty line before the command line's own), exit status 130."""


# The exit statuses of every command: 0 is success; these are the rest.
EXIT_GATE_FAILED = 1
"""``evaluate``: a pose's error is above ``--fail-above-cm`` or ``--fail-above-deg``."""
EXIT_TASKS_FAILED = 1
"""``sweep``: some tasks failed; their rows say why."""
EXIT_BAD_INPUT = 2
"""Bad input or usage: one line names what was wrong."""
EXIT_INTERNAL_ERROR = 70
"""A defect in segloc itself (EX_SOFTWARE)."""
EXIT_INTERRUPTED = 130
"""Stopped by Ctrl-C, SIGTERM or SIGHUP (128 + SIGINT)."""
