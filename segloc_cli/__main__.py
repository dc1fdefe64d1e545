"""The ``segloc`` console entry point (also ``python -m segloc_cli``).

SIGTERM and SIGHUP are made to interrupt like Ctrl-C before anything heavy is
imported, so a run stopped at any moment ends the way Ctrl-C ends it: one
line, exit status 130, whole-file outputs left as they were (``stopping.py``
keeps the interrupt out of imports and raises it again where library code
swallowed it). Commands that keep partial work (``localize``, ``record``) take
the signals over while they run and stop at their next safe point.
"""

from __future__ import annotations

import sys

from segloc_cli.errors import EXIT_INTERRUPTED
from segloc_cli.stopping import install_interrupts, interrupt_taken
from segloc_cli.wording import said


def main() -> None:
    """Install the signal handling, then run the command line."""
    install_interrupts()
    try:
        from segloc_cli.cli import main as run

        run()  # which reports an interrupt itself, once in it
    except KeyboardInterrupt:
        sys.stderr.write(said("interrupted") + "\n")
        sys.exit(EXIT_INTERRUPTED)
    finally:
        interrupt_taken()  # or the command ended before a stop signal's interrupt reached it


if __name__ == "__main__":
    main()
