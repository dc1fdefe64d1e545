"""A stop signal's interrupt under the entry point's handling (``stopping.install_interrupts``):
kept out of imports, raised again where library code swallowed it, and not raised twice into
the cleanup of the first. One fresh interpreter signals itself, so the timings are its own."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from segloc_cli.stopping import RETRY_S

SCRIPT = textwrap.dedent(
    """
    import os, signal, sys, time, weakref
    from segloc_cli.stopping import install_interrupts, interrupt_taken

    def stop():
        os.kill(os.getpid(), signal.SIGTERM)

    def wait_for_interrupt(seconds=3.0):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(0.005)

    install_interrupts()
    sys.path.insert(0, sys.argv[1])

    # 1. Signalled while a module is imported: the import ends, then the interrupt.
    try:
        import signalled_mid_import
        wait_for_interrupt()
        print("import: no interrupt")
    except KeyboardInterrupt:
        print("import:", "whole" if "signalled_mid_import" in sys.modules else "cut")
    interrupt_taken()

    # 2. Signalled in a weakref callback, whose exceptions Python reports and drops.
    class Thing:
        pass

    thing = Thing()
    keep = weakref.ref(thing, lambda _ref: stop())
    started = time.monotonic()
    try:
        del thing
        wait_for_interrupt()
        print("swallowed: no interrupt")
    except KeyboardInterrupt:
        print(f"swallowed: raised again after {time.monotonic() - started:.2f} s")
    interrupt_taken()

    # 3. The cleanup of a taken interrupt runs to its end, and nothing follows it.
    try:
        stop()
        wait_for_interrupt()
    except KeyboardInterrupt:
        try:
            wait_for_interrupt(4 * {retry})
            print("cleanup: whole")
        except KeyboardInterrupt:
            print("cleanup: cut")
    interrupt_taken()
    try:
        wait_for_interrupt(4 * {retry})
        print("after: quiet")
    except KeyboardInterrupt:
        print("after: interrupted again")
    """
).replace("{retry}", repr(RETRY_S))

MODULE = textwrap.dedent(
    """
    import os, signal, time
    os.kill(os.getpid(), signal.SIGTERM)
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        time.sleep(0.005)
    """
)


def test_an_interrupt_waits_out_imports_survives_swallowing_and_spares_cleanup(tmp_path):
    (tmp_path / "signalled_mid_import.py").write_text(MODULE, encoding="utf-8")
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "import: whole"
    swallowed, after_s = lines[1].rsplit(" after ", 1)
    assert swallowed == "swallowed: raised again"
    assert float(after_s.split()[0]) < 3 * RETRY_S
    assert lines[2:] == ["cleanup: whole", "after: quiet"]
    # Python's own report of what it dropped: the first raise, in the callback.
    assert "KeyboardInterrupt" in done.stderr
