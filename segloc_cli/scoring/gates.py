"""CI gates on scored estimates: what each gate asked, what was measured, and whether it held.

A gate bounds either each pose (``|X|`` and ``|Y|``, the position error's magnitude, ``|θ|``)
or a summary of all of them (RMS, mean, a percentile, the share of poses within the
per-pose limits). ``GateOutcome`` is one gate's result, as the Markdown summary, the JUnit
file and the HTML report show it; every function here is pure.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class GateOutcome:
    """One gate's result: ``name`` says what it bounds in words (``"RMS position error"``),
    ``measured`` and ``limit`` are in ``unit`` (``"cm"``, ``"°"`` or ``"%"``), ``passed``
    whether ``measured`` keeps to ``limit`` (``at_least``: a lower bound, as for the share
    of poses within limits; otherwise an upper bound). ``measured`` is NaN when nothing was
    there to measure, which fails the gate."""

    name: str
    measured: float
    limit: float
    unit: str
    passed: bool
    at_least: bool = False

    @property
    def text(self) -> str:
        """The outcome in one phrase: ``RMS position error 3.2 cm ≤ 5 cm: pass``."""
        sign = ("≥" if self.at_least else "≤") if self.passed else ("<" if self.at_least else ">")
        measured = "none" if self.measured != self.measured else f"{self.measured:.{_DECIMALS[self.unit]}f}"
        return f"{self.name} {measured} {self.unit} {sign} {self.limit:g} {self.unit}: " + (
            "pass" if self.passed else "FAIL"
        )


_DECIMALS = {"cm": 1, "°": 2, "%": 1}
