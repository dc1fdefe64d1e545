"""The simulated world: segments with a material each, as the simulator and the serial
emulator render them and world files (``io/maps.py``) hold them."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MATERIALS = ("wall", "glass")
"""What a segment is made of: a wall returns the beams that reach it, glass only some of them
(``sim.SensorModel.glass_return_prob``)."""


@dataclass(frozen=True)
class World:
    """A simulated environment.

    ``segments`` (M, 4) float64, metres, world frame; ``materials`` (M,) str, one
    of ``MATERIALS`` per segment; ``name`` a label for reports; ``sensor`` the
    scanner its file chooses to simulate it with, by the names of
    ``sim.SENSOR_CHOICES`` (``sim.sensor_model`` makes the model; {}: the defaults).
    """

    segments: np.ndarray
    materials: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=str))
    name: str = "world"
    sensor: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        segments = np.asarray(self.segments, dtype=float).reshape(-1, 4)
        materials = np.asarray(self.materials, dtype=str).reshape(-1)
        if materials.size == 0 and len(segments) > 0:
            materials = np.full(len(segments), "wall")
        if len(materials) != len(segments):
            raise ValueError(
                f"world {self.name!r}: {len(materials)} materials for {len(segments)} segments"
            )
        unknown = sorted(set(materials.tolist()) - set(MATERIALS))
        if unknown:
            raise ValueError(
                f"world {self.name!r}: unknown material(s) {unknown}; use one of {list(MATERIALS)}"
            )
        object.__setattr__(self, "segments", segments)
        object.__setattr__(self, "materials", materials)

    def __len__(self) -> int:
        return len(self.segments)
