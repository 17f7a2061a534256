"""Keeps the GL renderer in step with the session and the view state, and draws only on change."""

from __future__ import annotations

import numpy as np
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians

from .gl.renderer import FrameTimes, SplatRenderer, segmentation_from_weights
from .session import Scene
from .state import SegMode, ViewState

MASK_COLOR = (1.0, 0.85, 0.1)


class SceneView:
    """Owns a :class:`SplatRenderer`; :meth:`draw` re-renders only when the camera, the
    Gaussians or the view state changed since the last render."""

    def __init__(self, renderer: SplatRenderer) -> None:
        self.renderer = renderer
        self._last_key: tuple | None = None
        self._session_id: int | None = None
        self.last_times = FrameTimes()

    def sync(self, session: Scene, state: ViewState) -> None:
        """Upload changed Gaussians (only the edited particles') and apply the filters."""
        if self._session_id != id(session):
            self._session_id = id(session)
            session.take_changes()
            self.renderer.set_gaussians(session.gaussians())
        else:
            changed = session.take_changes()
            if changed is None:
                self.renderer.set_gaussians(session.gaussians())
            else:
                for owner in sorted(changed):
                    self.renderer.replace_owner(owner, session.particle_gaussians(owner))
        self.renderer.set_filter(state.visible_owners(session.owner_ids()), state.prune)

    def draw(
        self, session: Scene, state: ViewState, camera: Camera, *, force: bool = False, finish: bool = False
    ) -> FrameTimes | None:
        """Render ``camera`` if anything changed (or ``force``); returns the timings or None."""
        self.sync(session, state)
        c2w = camera.c2w.detach().cpu().numpy().tobytes()
        key = (
            c2w,
            camera.K.detach().cpu().numpy().tobytes(),
            camera.width,
            camera.height,
            session.version,
            id(session),
            state.key(),
        )
        if key == self._last_key and not force:
            return None
        mode = state.color_mode()
        objects = session.objects().tolist() if mode == 2 else None
        times = self.renderer.render(camera, color_mode=mode, objects=objects, finish=finish)
        if state.seg_mode is SegMode.MASK_SELECTED and state.selected is not None:
            self.renderer.render_mask(camera, state.selected)
        self._last_key = key
        self.last_times = times
        return times

    def invalidate(self) -> None:
        """Force the next :meth:`draw` to render."""
        self._last_key = None

    def present(self, state: ViewState, viewport: tuple[int, int, int, int]) -> None:
        """Blit the last render into ``viewport`` of the bound framebuffer."""
        mask = MASK_COLOR if state.seg_mode is SegMode.MASK_SELECTED and state.selected is not None else None
        self.renderer.blit(viewport, state.background, mask)

    def pick(self, session: Scene, camera: Camera, x: int, y: int) -> int:
        """Owner dominating pixel (x, y) of ``camera``'s image (-1 = background or empty)."""
        w, h = camera.width, camera.height
        if not (0 <= x < w and 0 <= y < h):
            return -1
        weights, alpha = self.renderer.owner_weights(camera, session.num_owners(), region=(x, y, 1, 1))
        self.invalidate()
        return int(segmentation_from_weights(weights, alpha)[0, 0])

    def image(self, session: Scene, state: ViewState, camera: Camera) -> np.ndarray:
        """Render ``camera`` (any size, offscreen) and return (H, W, 3) float32 over the background."""
        self.draw(session, state, camera, force=True)
        rgb = self.renderer.read_rgb(state.background)
        self.invalidate()
        return np.clip(rgb, 0.0, 1.0)

    def visible_gaussians(self, session: Scene, state: ViewState) -> Gaussians:
        """The Gaussians as drawn: edited, filtered by visibility, segmentation mode and pruning."""
        g = session.gaussians()
        owners = torch.tensor(state.visible_owners(session.owner_ids()), dtype=torch.int64)
        keep = torch.isin(g.owner, owners) & (g.opacities >= state.prune)
        return g.subset(keep)
