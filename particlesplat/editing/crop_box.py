"""The crop box: a world-aligned box outside which a scene's Gaussians are hidden, and the box about a robot
scene's workspace.

An edit file's ``crop`` operation (:class:`particlesplat.editing.operations.Crop`) sets the box, which
``particlesplat render`` and ``particlesplat export`` apply to the Gaussians they draw and write: a Gaussian is kept
when its mean lies inside the box (bounds included). A robot scene's far background (the walls of its room, metres
away) sets the bounds of what it exports, so that another viewer frames the room and shows the table tiny inside
it; ``export`` crops a scene whose edits set no box to :func:`workspace_box`, the box about its table and arm (the
points its default view keeps in sight, :class:`particlesplat.core.viewpoints.Framing`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from os import PathLike
from typing import Any

import torch
from torch import Tensor

from particlesplat.core.errors import short_repr
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.limits import WORLD_MAX_METRES
from particlesplat.core.world import SUPPORT_Z
from particlesplat.editing.edit_fields import read_numbers, rounded
from particlesplat.editing.particle_edits import EditsError

# the workspace box about a robot scene's table and arm: this far (metres) beyond them sideways and above, and
# this far below the support surface (the table top's Gaussians lie within a centimetre or two of it)
WORKSPACE_MARGIN = 0.10
WORKSPACE_ABOVE = 0.15
WORKSPACE_BELOW = 0.05


@dataclass(frozen=True)
class CropBox:
    """The world-aligned box from ``lo`` to ``hi`` (x, y, z world metres, each ``lo`` below its ``hi``); infinite
    bounds (:meth:`everything`) hide nothing."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    @classmethod
    def everything(cls) -> CropBox:
        """The box that hides nothing (an edit file's ``crop: false``)."""
        return cls((-math.inf, -math.inf, -math.inf), (math.inf, math.inf, math.inf))

    @property
    def bounded(self) -> bool:
        """Whether it hides anything at all (a finite bound)."""
        return any(math.isfinite(v) for v in (*self.lo, *self.hi))

    def inside(self, points: Tensor) -> Tensor:
        """(N,) bool: which of ``points`` (N, 3) world metres lie in the box, bounds included."""
        p = points.detach().double()
        lo = torch.tensor(self.lo, dtype=torch.float64, device=p.device)
        hi = torch.tensor(self.hi, dtype=torch.float64, device=p.device)
        return ((p >= lo) & (p <= hi)).all(dim=-1)

    def crop(self, gaussians: Gaussians) -> Gaussians:
        """The Gaussians whose means lie in the box (all of them for :meth:`everything`)."""
        if not self.bounded:
            return gaussians
        return gaussians.subset(self.inside(gaussians.means))

    def text(self) -> str:
        """The box for a message: ``x -0.66..0.50, y -0.50..0.50, z -0.05..1.02 m``."""
        if not self.bounded:
            return "no box"
        axes = zip("xyz", self.lo, self.hi, strict=True)
        return ", ".join(f"{a} {lo:.2f}..{hi:.2f}" for a, lo, hi in axes) + " m"


def read_crop(value: Any, where: str) -> CropBox:
    """An edit file's ``crop`` value: ``{min: [x, y, z], max: [x, y, z]}`` world metres (each within the world's
    +-1e5 m, ``min`` below ``max`` on every axis), or ``false`` (no box: everything shows)."""
    if value is False:
        return CropBox.everything()
    if not isinstance(value, dict) or set(value) != {"min", "max"}:
        raise EditsError(f"{where}: expected {{min: [x, y, z], max: [x, y, z]}} or false, got {short_repr(value)}")
    lo, hi = read_numbers(value["min"], 3, f"{where}.min"), read_numbers(value["max"], 3, f"{where}.max")
    for name, bound in (("min", lo), ("max", hi)):
        if max(abs(v) for v in bound) > WORLD_MAX_METRES:
            raise EditsError(f"{where}.{name}: beyond {WORLD_MAX_METRES:g} m from the origin, got {short_repr(bound)}")
    for axis, a, b in zip("xyz", lo, hi, strict=True):
        if not a < b:
            raise EditsError(f"{where}: min {axis} {a:g} is not below max {axis} {b:g}")
    return CropBox((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))


def crop_yaml(box: CropBox) -> Any:
    """What an edit file holds under ``crop`` (inverse of :func:`read_crop`)."""
    if not box.bounded:
        return False
    return {"min": rounded(box.lo), "max": rounded(box.hi)}


def workspace_box(folder: str | PathLike) -> CropBox | None:
    """The box about a robot scene's workspace: its table top and arm (the points its default view keeps in sight,
    ``keep`` of :func:`particlesplat.data.scene_meta.read_framing`), :data:`WORKSPACE_MARGIN` beyond them
    sideways, :data:`WORKSPACE_ABOVE` above the highest and :data:`WORKSPACE_BELOW` below the support surface.
    None for a scene that records no such points (a tabletop scene, a capture without scene.json)."""
    from particlesplat.data.scene_meta import read_framing

    framing = read_framing(folder)
    if framing is None or not framing.keep:
        return None
    pts = torch.tensor(framing.keep, dtype=torch.float64)
    lo, hi = pts.min(0).values - WORKSPACE_MARGIN, pts.max(0).values + WORKSPACE_MARGIN
    bottom = min(SUPPORT_Z, float(pts[:, 2].min())) - WORKSPACE_BELOW
    top = float(pts[:, 2].max()) + WORKSPACE_ABOVE
    return CropBox((float(lo[0]), float(lo[1]), bottom), (float(hi[0]), float(hi[1]), top))
