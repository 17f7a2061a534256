"""Headless MuJoCo rendering of a composed robot workspace: colour, planar depth and instance masks.

Two GL passes per view: the shaded colour pass (lights, shadows, textures, 4x multisampling) and one
segmentation pass whose colour buffer holds geom ids and whose depth buffer gives the depth, so depth
and masks come from the same rasterisation (no anti-aliasing). MuJoCo renders with reversed Z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .robot_assets import gl_error
from .robot_compose import HIDDEN_GROUP, Composition


@dataclass
class Views:
    """Rendered views: rgb (V, H, W, 3) uint8; depth (V, H, W) float32 planar metres, 0 = nothing (sky);
    masks (V, H, W) uint8 instance ids, 0 = background (table, arm, floor, walls)."""

    rgb: np.ndarray
    depth: np.ndarray
    masks: np.ndarray


class SceneRenderer:
    """A GL context and MuJoCo render context for one compiled model (``width`` x ``height`` pixels).
    ``skybox`` False skips drawing the sky, for cameras that never see it (a full-screen pass on llvmpipe)."""

    def __init__(self, mujoco, comp: Composition, width: int, height: int, skybox: bool = True) -> None:
        self.mujoco, self.comp, self.width, self.height = mujoco, comp, width, height
        self.skybox = skybox
        try:
            self.gl = mujoco.GLContext(width, height)
            self.gl.make_current()
            self.ctx = mujoco.MjrContext(comp.model, mujoco.mjtFontScale.mjFONTSCALE_150)
        except Exception as e:  # noqa: BLE001 - GL failures surface as many exception types
            raise gl_error(e) from e
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.ctx)
        self.ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # read the reversed-Z buffer as stored
        self.scene = mujoco.MjvScene(comp.model, maxgeom=4000)
        self.option = mujoco.MjvOption()
        self.option.sitegroup[:] = 0
        self.option.geomgroup[HIDDEN_GROUP] = 0
        self.rect = mujoco.MjrRect(0, 0, width, height)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED

    def close(self) -> None:
        self.ctx.free()
        self.gl.free()

    def _draw(self, camera_id: int, segment: bool) -> None:
        m, mj = self.comp.model, self.mujoco
        self.camera.fixedcamid = camera_id
        mj.mjv_updateScene(m, self.comp.data, self.option, None, self.camera, mj.mjtCatBit.mjCAT_ALL, self.scene)
        self.scene.flags[mj.mjtRndFlag.mjRND_REFLECTION] = False  # the floor's 1 % mirror: a second scene pass
        self.scene.flags[mj.mjtRndFlag.mjRND_SEGMENT] = segment
        self.scene.flags[mj.mjtRndFlag.mjRND_IDCOLOR] = segment
        self.scene.flags[mj.mjtRndFlag.mjRND_SKYBOX] = self.skybox
        mj.mjr_render(self.rect, self.scene, self.ctx)

    def render(self, camera_ids: list[int]) -> Views:
        """Render the cameras ``camera_ids`` at the current ``comp.data`` state."""
        mj, m = self.mujoco, self.comp.model
        h, w = self.height, self.width
        near = np.float32(m.vis.map.znear * m.stat.extent)
        far = np.float32(m.vis.map.zfar * m.stat.extent)
        # reversed-Z perspective: window depth z_w = d / z_eye - c  =>  z_eye = d / (z_w + c)
        c = np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5)
        d = np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near))
        geom = int(mj.mjtObj.mjOBJ_GEOM)
        rgbs, depths, masks = [], [], []
        rgb = np.empty((h, w, 3), np.uint8)
        ids = np.empty((h, w, 3), np.uint8)
        zbuf = np.empty((h, w), np.float32)
        for cam in camera_ids:
            self._draw(cam, segment=False)
            mj.mjr_readPixels(rgb, None, self.rect, self.ctx)
            rgbs.append(np.flipud(rgb).copy())
            self._draw(cam, segment=True)
            mj.mjr_readPixels(ids, zbuf, self.rect, self.ctx)
            seg = (
                ids[..., 0].astype(np.int64)
                + (ids[..., 1].astype(np.int64) << 8)
                + (ids[..., 2].astype(np.int64) << 16)
            )
            inst = np.zeros(self.scene.ngeom + 1, np.uint8)  # segid + 1 -> instance; 0 = nothing drawn
            for g in self.scene.geoms[: self.scene.ngeom]:
                if g.segid >= 0 and g.objtype == geom:
                    inst[g.segid + 1] = self.comp.geom_instance[g.objid]
            hit = seg > 0
            z = np.where(hit, d / (zbuf.astype(np.float64) + c), 0.0)
            masks.append(np.flipud(inst[np.clip(seg, 0, self.scene.ngeom)]).copy())
            depths.append(np.flipud(z).astype(np.float32))
        return Views(np.stack(rgbs), np.stack(depths), np.stack(masks))
