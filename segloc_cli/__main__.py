"""The ``segloc`` console entry point (also ``python -m segloc_cli``).

SIGTERM and SIGHUP are made to interrupt like Ctrl-C before anything heavy is
imported, so a run stopped at any moment ends the way Ctrl-C ends it: one
line, exit status 130, whole-file outputs left as they were. Commands that
keep partial work (``localize``, ``record``) take the signals over while they
run and stop at their next safe point.
"""

from __future__ import annotations

import signal
import sys

from segloc_cli.errors import EXIT_INTERRUPTED
from segloc_cli.wording import said


def main() -> None:
    """Install the signal handling, then run the command line."""
    for name in ("SIGTERM", "SIGHUP"):
        signum = getattr(signal, name, None)
        if signum is not None:
            signal.signal(signum, signal.default_int_handler)
    try:
        from segloc_cli.cli import main as run
    except KeyboardInterrupt:
        sys.stderr.write(said("interrupted") + "\n")
        sys.exit(EXIT_INTERRUPTED)
    run()


if __name__ == "__main__":
    main()
