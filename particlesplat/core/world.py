"""The world frame every scene and model shares (docs/dataset.md): metres, +z up, and the surface objects rest
on, the tabletop family's floor and the robot family's table top, at z = :data:`SUPPORT_Z`.
``particlesplat scene check`` brings a capture into it. A scene with a table (the robot family's) also has a floor
below it, where an object past the table's edge rests (:class:`Support`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

SUPPORT_Z = 0.0  # metres: the height of the support surface objects rest on
ON_SUPPORT = 0.01  # metres about the support surface within which a point seen in depth lies on it
BELOW_SUPPORT = 0.02  # metres under it below which a point seen in depth lies past it (the floor, a table's sides)


@dataclass(frozen=True)
class Support:
    """What objects rest on in one scene, world metres: a table top at :data:`SUPPORT_Z` over the rectangle
    |x| <= ``table_half[0]``, |y| <= ``table_half[1]`` about the origin (the robot family's table, as its
    ``scene.json`` records ``table_half_extent``), and the floor at ``floor_z`` around it; without a table
    (``table_half`` None), the floor at :data:`SUPPORT_Z` everywhere (the tabletop family's)."""

    table_half: tuple[float, float] | None = None
    floor_z: float = SUPPORT_Z

    def on_table(self, x: float, y: float) -> bool:
        """Whether (x, y) lies over the table top (edges included); False without a table."""
        return self.table_half is not None and abs(x) <= self.table_half[0] and abs(y) <= self.table_half[1]

    def height_at(self, x: float, y: float) -> float:
        """The height (world z, metres) of the surface an object whose centre is at (x, y) rests on: the table top
        over the table, the floor elsewhere (and everywhere without a table)."""
        return SUPPORT_Z if self.table_half is None or self.on_table(x, y) else self.floor_z

    def surface_at(self, x: float, y: float) -> str:
        """What an object at (x, y) rests on, for a message: ``"table"`` or ``"floor"``."""
        return "table" if self.on_table(x, y) else "floor"

    def table_gap(self, x: float, y: float) -> float:
        """Metres from (x, y) to the table top's rectangle in x, y (0 over it; infinite without a table): how far
        a point on the floor is from the table's side."""
        if self.table_half is None:
            return math.inf
        dx, dy = max(abs(x) - self.table_half[0], 0.0), max(abs(y) - self.table_half[1], 0.0)
        return math.hypot(dx, dy)
