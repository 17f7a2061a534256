"""Keeps the GL renderer in step with the session and the view state, and draws only on change."""

from __future__ import annotations

import numpy as np
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.model.support_map import support_map_image

from .gl.renderer import FrameTimes, SplatRenderer, segmentation_from_weights
from .session import Scene, session_particles
from .state import SegMode, ViewState

MASK_COLOR = (1.0, 0.85, 0.1)


def session_support_map(session: Scene) -> torch.Tensor | None:
    """The support map (4, N, N) float32 on the CPU the session's particles read from their views, or None (a .ply,
    a model without ``background.support_map``, a scene without depth)."""
    particles = session_particles(session)
    found = None if particles is None else particles.support_map
    return None if found is None else found.detach().to("cpu", torch.float32)


class SceneView:
    """Owns a :class:`SplatRenderer`; :meth:`draw` re-renders only when the camera, the
    Gaussians or the view state changed since the last render."""

    def __init__(self, renderer: SplatRenderer) -> None:
        self.renderer = renderer
        self._last_key: tuple | None = None
        self._session_id: int | None = None
        self._camera: Camera | None = None  # the last render's
        self._support_map: torch.Tensor | None = None  # the session's (4, N, N), or None
        self.last_times = FrameTimes()

    def sync(self, session: Scene, state: ViewState) -> None:
        """Upload changed Gaussians (only the edited particles') and apply the filters."""
        if self._session_id != id(session):
            self._session_id = id(session)
            session.take_changes()
            self.renderer.set_gaussians(session.gaussians())
            self._support_map = session_support_map(session)
            arr = None if self._support_map is None else self._support_map.permute(1, 2, 0).numpy()
            self.renderer.set_support_map(arr)
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
        self._camera = camera
        self.last_times = times
        return times

    def invalidate(self) -> None:
        """Force the next :meth:`draw` to render."""
        self._last_key = None

    def present(self, state: ViewState, viewport: tuple[int, int, int, int]) -> None:
        """Blit the last render into ``viewport`` of the bound framebuffer."""
        mask = MASK_COLOR if state.seg_mode is SegMode.MASK_SELECTED and state.selected is not None else None
        support = self._camera if self._draws_support_map(state) else None
        self.renderer.blit(viewport, state.background, mask, support)

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
        rgb = self.renderer.read_rgb(self.backdrop(state, camera))
        self.invalidate()
        return np.clip(rgb, 0.0, 1.0)

    def backdrop(self, state: ViewState, camera: Camera) -> tuple[float, float, float] | np.ndarray:
        """What is behind the Gaussians in ``camera``, as :meth:`present` draws it: the background colour, or
        with the support map on, (H, W, 3) float32 of the support map over it (its torch twin)."""
        if not self._draws_support_map(state) or self._support_map is None:
            return state.background
        colour = torch.tensor(state.background, dtype=torch.float32)
        return support_map_image(self._support_map, colour, camera.to("cpu", torch.float32)).numpy()

    def _draws_support_map(self, state: ViewState) -> bool:
        """The support map is drawn behind the scene's own colours (not behind a colour per particle or object)."""
        return state.support_map and state.color_mode() == 0 and self._support_map is not None

    def visible_gaussians(self, session: Scene, state: ViewState) -> Gaussians:
        """The Gaussians as drawn: edited, filtered by visibility, segmentation mode and pruning."""
        g = session.gaussians()
        owners = torch.tensor(state.visible_owners(session.owner_ids()), dtype=torch.int64)
        keep = torch.isin(g.owner, owners) & (g.opacities >= state.prune)
        return g.subset(keep)
