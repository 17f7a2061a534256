"""View state the panels change: selection, visibility, segmentation mode, pruning, render scale."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum

from particlesplat.core.viewpoints import DEFAULT_BACKGROUND

# Gaussians fainter than this are not drawn by default: on the 32 test scenes they are 38 % of the shipped
# model's Gaussians (half of them of inactive particles, z_t ~ 0) and its PSNR is 28.18 dB without them, 28.15 with
DEFAULT_PRUNE = 0.05


class SegMode(StrEnum):
    """How the scene is coloured and what of it is drawn; the value is the panel's label."""

    NORMAL = "normal"
    BY_PARTICLE = "colour by particle"
    BY_OBJECT = "colour by object"
    MASK_SELECTED = "mask of selected"
    BACKGROUND_HIDDEN = "background hidden"
    BACKGROUND_ALONE = "background alone"
    KEYPOINTS = "keypoints"  # the particles' 3D keypoints over the scene (particle_overlay)
    BOXES = "boxes"  # the particles' 3D boxes over the scene (particle_overlay)


SEG_MODES: tuple[SegMode, ...] = tuple(SegMode)  # in the panel's and the M key's order
EMPTY_MASK = "mask of selected: nothing is selected, so nothing is masked (click an object)"


@dataclass
class ViewState:
    """Everything about *how* the scene is shown (not what it is: that is the session).

    Attributes:
        selected: selected particle index or None.
        previous: the particle selected before it (what Merge joins the selection with), or None.
        hidden: particle indices hidden by their visibility toggle.
        solo: a particle shown alone (plus the background unless hidden), or None.
        seg_mode: a :class:`SegMode` (its label string is accepted and converted).
        prune: opacity threshold; Gaussians below it are not drawn (and not exported). Default
            :data:`DEFAULT_PRUNE`.
        background: RGB behind the Gaussians.
        support_map: where the scene's particles carry a support map (``background.support_map``), draw it behind
            the Gaussians where a ray meets the support surface (over ``background`` elsewhere), in the normal
            colour mode.
        overlay: show the frame-time / count overlay.
        panel: show the ImGui panel.
        moving_scale: render scale while the camera or a particle is being dragged.
        gizmo_scale: the gizmo shows its scale handles instead of its move handles.
        ruler: a click picks a ruler point (:mod:`viewer.tools.ruler`) instead of selecting; ruler_points: its
            points (world metres, at most two).
    """

    selected: int | None = None
    previous: int | None = None
    hidden: set[int] = field(default_factory=set)
    solo: int | None = None
    seg_mode: SegMode = SegMode.NORMAL
    prune: float = DEFAULT_PRUNE
    background: tuple[float, float, float] = DEFAULT_BACKGROUND
    support_map: bool = True
    overlay: bool = True
    panel: bool = True
    moving_scale: float = 0.5
    gizmo_scale: bool = False
    ruler: bool = False
    ruler_points: list[tuple[float, float, float]] = field(default_factory=list)

    def __setattr__(self, name, value) -> None:
        if name == "seg_mode":
            value = SegMode(value)  # a label that is no mode raises ValueError here, not a silent normal view
        if name == "selected" and value is not None and getattr(self, "selected", None) not in (None, value):
            super().__setattr__("previous", self.selected)
        super().__setattr__(name, value)

    def visible_owners(self, owners: int | Iterable[int]) -> list[int]:
        """Owners to draw (-1 = background) under the visibility, solo and segmentation modes.

        owners: the scene's particle owners (>= 0), or their count P for owners 0..P-1. A .ply passes the
        owners it holds, so a sparse owner set costs its size, not its largest index."""
        if self.seg_mode is SegMode.BACKGROUND_ALONE:
            return [-1]
        present = range(owners) if isinstance(owners, int) else owners
        owners = [self.solo] if self.solo is not None else [i for i in present if i not in self.hidden]
        if self.seg_mode is not SegMode.BACKGROUND_HIDDEN:
            owners.append(-1)
        return owners

    def mode_note(self) -> str | None:
        """What the status line should say of the mode as it is: :data:`EMPTY_MASK` in "mask of selected" with
        nothing selected (the image is the normal one), else None."""
        return EMPTY_MASK if self.seg_mode is SegMode.MASK_SELECTED and self.selected is None else None

    def color_mode(self) -> int:
        """Colour mode of the splat pass: 1 = a colour per particle, 2 = a colour per object."""
        return {SegMode.BY_PARTICLE: 1, SegMode.BY_OBJECT: 2}.get(self.seg_mode, 0)

    def key(self) -> tuple:
        """Everything that changes the rendered pixels."""
        return (
            self.selected if self.seg_mode is SegMode.MASK_SELECTED else None,
            tuple(sorted(self.hidden)),
            self.solo,
            self.seg_mode,
            self.prune,
            self.background,
            self.support_map,
        )
