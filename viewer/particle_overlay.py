"""The "keypoints" and "boxes" segmentation modes: the particles' 3D keypoints and boxes drawn over the scene.

The marks are those of ``particlesplat render --mode keypoints|boxes``
(:func:`particlesplat.analysis.figures.overlay_marks`), from the scene's particle arrays
(:func:`particlesplat.analysis.particle_arrays.particle_arrays`, recomputed when the particles change) projected
into the view camera, and drawn with ImGui's background draw list (over the scene, under the panels).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from particlesplat.analysis.figures import Mark, overlay_marks
from particlesplat.analysis.particle_arrays import ParticleArrays, particle_arrays
from particlesplat.core.camera import Camera

if TYPE_CHECKING:
    from .session import Scene

OVERLAY_MODES = ("keypoints", "boxes")


class ParticleOverlay:
    """Keeps the particle arrays of the session in step (by ``session.version``) and draws the marks."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._arrays: ParticleArrays | None = None

    def arrays(self, session: Scene) -> ParticleArrays | None:
        """The session's particle arrays (None for a .ply: no particles)."""
        editor = session.editor
        if editor is None:
            return None
        key = (id(session), session.version)
        if key != self._key:
            self._key = key
            self._arrays = particle_arrays(editor.model, editor.particles)
        return self._arrays

    def marks(self, session: Scene, mode: str, camera: Camera) -> list[Mark]:
        """The marks of ``mode`` (keypoints or boxes) in ``camera``'s framebuffer pixels; none otherwise."""
        arrays = self.arrays(session) if mode in OVERLAY_MODES else None
        return [] if arrays is None else overlay_marks(arrays, camera, "keypoints" if mode == "keypoints" else "boxes")

    def draw(self, session: Scene, mode: str, camera: Camera, pixel_ratio: tuple[float, float]) -> int:
        """Draw the marks (``pixel_ratio``: framebuffer pixels per window point). Returns how many."""
        from imgui_bundle import imgui

        marks = self.marks(session, mode, camera)
        if not marks:
            return 0
        sx, sy = pixel_ratio
        draw = imgui.get_background_draw_list()
        for m in marks:
            r, g, b = (int(255 * c) for c in m.colour)
            col = imgui.IM_COL32(r, g, b, 255)
            pts = [imgui.ImVec2(float(u) / sx, float(v) / sy) for u, v in m.points]
            if m.kind == "dot":
                draw.add_circle_filled(pts[0], m.radius / sx, col)
                draw.add_circle(pts[0], m.radius / sx, imgui.IM_COL32(0, 0, 0, 255), 0, m.width)
            elif m.kind == "ring":
                draw.add_circle(pts[0], m.radius / sx, col, 0, m.width)
            else:
                draw.add_line(pts[0], pts[1], col, m.width)
        return len(marks)
