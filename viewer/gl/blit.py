"""The last pass of a frame: the splat render drawn over the background into the window (``blit.frag``), with the
selected mask's tint and, for a model that reads the support surface's map from its views, that map behind the
Gaussians where a pixel's ray meets the support surface (the GL twin of :mod:`particlesplat.model.support_map`)."""

from __future__ import annotations

import moderngl
import numpy as np

from particlesplat.core.camera import Camera
from particlesplat.core.world import SUPPORT_Z
from particlesplat.model.support_map import EDGE_SOFTNESS, HALF_EXTENT

from .shaders import load_shader


def blit_defines(mask: bool, support_map: bool) -> dict[str, str | int]:
    """blit.frag's variant: with the mask tint, with the support map behind the render."""
    return {**({"MASK": 1} if mask else {}), **({"SUPPORT_MAP": 1} if support_map else {})}


class Blit:
    """The blit programs (one per variant: mask tint, support map) and the support map's texture.

    Args:
        ctx: the moderngl context the splat renderer draws with.
        defines: how the colour target encodes a render (``COVERAGE_ALPHA``, ``UNORM_T``, ``COLOR_SCALE``: the
            splat renderer's compositing path and colour target).
    """

    def __init__(self, ctx: moderngl.Context, defines: dict[str, str | int]) -> None:
        self.ctx = ctx
        self._programs = {  # (mask tint, support map): without and with each
            (m, s): ctx.program(
                vertex_shader=load_shader("fullscreen.vert"),
                fragment_shader=load_shader("blit.frag", {**defines, **blit_defines(m, s)}),
            )
            for m in (False, True)
            for s in (False, True)
        }
        self._vaos = {m: ctx.vertex_array(p, []) for m, p in self._programs.items()}
        self._support_tex: moderngl.Texture | None = None  # set_support_map's

    def set_support_map(self, support_map: np.ndarray | None) -> None:
        """The scene's support map (:mod:`particlesplat.model.support_map`): (N, N, 4) RGB and support share, rows
        along world y from -HALF_EXTENT; None: none (a blit draws the background colour alone)."""
        if self._support_tex is not None:
            self._support_tex.release()
            self._support_tex = None
        if support_map is None:
            return
        n = support_map.shape[0]
        if support_map.shape != (n, n, 4):
            raise ValueError(f"set_support_map: expected (N, N, 4), got {support_map.shape}")
        # half floats filter linearly on every GL 3.3 driver (float32 textures need not)
        tex = self.ctx.texture((n, n), 4, data=np.ascontiguousarray(support_map, np.float16).tobytes(), dtype="f2")
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x = tex.repeat_y = False  # clamp to the edge texels, as the torch twin's border padding
        self._support_tex = tex

    def _bind_support_map(self, prog: moderngl.Program, camera: Camera) -> None:
        """The uniforms of blit.frag's SUPPORT_MAP part for ``camera`` (the camera of the last render)."""
        assert self._support_tex is not None
        self._support_tex.use(2)
        prog["support_map"] = 2
        K = camera.K.detach().double().cpu().numpy()
        c2w = camera.c2w.detach().double().cpu().numpy()
        prog["cam_rot"] = tuple(float(v) for v in c2w[:3, :3].T.reshape(-1))  # column-major
        prog["cam_eye"] = tuple(float(v) for v in c2w[:3, 3])
        prog["intrinsics"] = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
        prog["image_size"] = (float(camera.width), float(camera.height))
        prog["support_z"] = float(SUPPORT_Z)
        prog["support_half"] = float(HALF_EXTENT)
        prog["edge_softness"] = float(EDGE_SOFTNESS)

    def draw(
        self,
        viewport: tuple[int, int, int, int],
        background: tuple[float, float, float],
        color: moderngl.Texture,
        mask: tuple[moderngl.Texture, tuple[float, float, float]] | None = None,
        support_camera: Camera | None = None,
    ) -> None:
        """Draw the render ``color`` over ``background`` into the bound framebuffer's ``viewport`` (x, y, w, h in
        GL pixels); ``mask``: a mask target and the colour to tint it with. With ``support_camera`` (the render's
        camera) and a :meth:`set_support_map`, over the support map where a pixel's ray meets it."""
        self.ctx.viewport = viewport
        self.ctx.disable(moderngl.BLEND)
        # one texel a pixel: nearest (exact, and cheaper on llvmpipe); scaled (moving frames): linear
        same = tuple(viewport[2:]) == tuple(color.size)
        filt = (moderngl.NEAREST, moderngl.NEAREST) if same else (moderngl.LINEAR, moderngl.LINEAR)
        if color.filter != filt:
            color.filter = filt
        color.use(0)
        support = support_camera is not None and self._support_tex is not None
        prog = self._programs[mask is not None, support]
        prog["image"] = 0
        prog["background"] = tuple(background)
        if support_camera is not None and support:
            self._bind_support_map(prog, support_camera)
        if mask is not None:
            mask_tex, mask_color = mask
            if mask_tex.filter != filt:
                mask_tex.filter = filt
            mask_tex.use(1)
            prog["mask"] = 1
            prog["mask_color"] = tuple(mask_color)
        self._vaos[mask is not None, support].render(moderngl.TRIANGLE_STRIP, vertices=4)

    def release(self) -> None:
        """Free the GL objects."""
        for obj in [self._support_tex, *self._vaos.values(), *self._programs.values()]:
            if obj is not None:
                obj.release()
