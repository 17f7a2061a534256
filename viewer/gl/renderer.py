"""The GL splat renderer: draws :class:`~particlesplat.core.gaussians.Gaussians` the way
:func:`particlesplat.render` does, fast enough for an interactive viewer on llvmpipe.

Design (see shaders/):

* The Gaussians live in one static RGBA32F texture (``row`` Gaussians per texture row, at most
  ``ROW`` and as many as the driver's texture size allows,
  ``texels`` texels each: mean + opacity, rotation rows + scales, owner, SH; packed by :mod:`viewer.gl.packing`).
  Only the rows of a changed particle are re-uploaded.
* When the view, the data or the filter changed: one global sort of the visible Gaussians by
  float32 camera z (:class:`~viewer.gl.depth_sort.DepthSorter`: numpy, or torch on a CUDA GPU), the sorted
  indices uploaded, then a projection pass
  that draws one fragment per splat (``project.frag``, on all rasteriser threads): 2D centre,
  conic, the radii of the alpha >= 1/255 ellipse and the SH colour, written in sorted order.
* A splat pass draws one point sprite (``auto`` when every splat fits the driver's point size
  and the guard band) or one oriented quad per splat into an offscreen float framebuffer, front
  to back. Compositing (chosen per context, :mod:`viewer.gl.caps`): ``fetch`` composites in the
  fragment shader with framebuffer fetch exactly like the torch renderer (alpha clamped at
  ALPHA_MAX, footprint alpha >= ALPHA_MIN, a pixel stops before the splat that would take its
  transmittance to <= T_MIN); ``blend`` (core GL 3.3) blends premultiplied colour with
  fixed-function blending, destination alpha holding 1 - T, with no early stop. The colour target is
  16-bit normalized by default (``color_dtype="nu2"``: 10-15 % faster splat passes on llvmpipe than float32,
  colour clamped to [0, 1] as the display does; ``fetch`` then keeps T as 0.5 + 0.5 T, 0.5 T once stopped).
* An id pass writes per-owner weights ``sum T alpha`` (24 owners per pass, 8 float
  attachments) for picking, masks and segmentation.
* The blit (:mod:`viewer.gl.blit`) draws the last render over the background into the window, with a mask's
  tint and the support map behind it. Shader sources come from :mod:`viewer.gl.shaders`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, TypeVar

import moderngl
import numpy as np

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.rendering.projection import DILATION

from .blit import Blit
from .caps import Compositing, GLCaps, probe
from .depth_sort import DepthSorter, SortDevice, resolve_sort_device
from .packing import camera_uniforms, pack_gaussians, row_for, texels_for
from .shaders import load_shader

T = TypeVar("T")


def _made(resource: T | None, what: str) -> T:
    """A GL resource made earlier (:meth:`SplatRenderer.set_gaussians`, the target's size); RuntimeError if not."""
    if resource is None:
        raise RuntimeError(f"SplatRenderer: no {what} yet (set the Gaussians and render first)")
    return resource


ID_ATTACHMENTS = 8  # float attachments of the id pass: 3 owners each (core GL 3.3 guarantees 8)
OWNERS_PER_ID_PASS = 3 * ID_ATTACHMENTS
PRIMITIVES = ("auto", "quads", "points")
ColorDtype = Literal["nu2", "f4", "f2"]
COLOR_DTYPES: tuple[ColorDtype, ...] = ("nu2", "f4", "f2")  # colour targets: 16-bit normalized, float32, half float
# blend into a normalized target: the colour is stored over this, so a splat's alpha x colour (and a pixel's sum)
# up to it is kept (in steps of COLOR_SCALE / 65535)
COLOR_SCALE = 8.0
MAX_KEYED = 64  # owners 0 .. MAX_KEYED - 1 can take another owner's colour (colour by object)
POINT_GUARD = 128  # viewport margin (pixels) of the point pass: sprites up to 2 * POINT_GUARD - 1 px stay whole
# pixels a splat's primitive reaches beyond its alpha >= ALPHA_MIN ellipse on each side (the radii are exact in float32
# to far less: 0.1 px only keeps pixel centres that round onto the ellipse inside; 0.5 cost 2-7 % more fill)
SPLAT_MARGIN = 0.1
# ``auto`` cost model (ms per splat, ms per rasterised pixel), fitted on llvmpipe (Mesa 22.3, 2
# cores): sprites have cheaper vertices and pixels but cover the whole square of the major axis
POINT_COST = (1.35e-3, 7.7e-6)
QUAD_COST = (2.07e-3, 11.0e-6)


def point_max_radius(caps: GLCaps) -> float:
    """Largest splat radius (pixels) drawn whole as a point sprite (side 2 (r + SPLAT_MARGIN)): the driver's point
    size limit, and the guard band that keeps sprites with off-screen centres."""
    return min(caps.max_point_size / 2.0 - SPLAT_MARGIN, POINT_GUARD - 1.0)


@dataclass
class FrameTimes:
    """Timings of one :meth:`SplatRenderer.render` call in milliseconds (CPU wall time). ``draw_ms``
    includes the GPU work only with ``render(..., finish=True)``. With ``render(..., profile=True)`` every
    GPU pass is bracketed by ``glFinish`` (which keeps llvmpipe from overlapping them: for profiles, not
    frame times): ``project_ms`` (projection pass), ``choose_ms`` (the ``auto`` primitive's choice),
    ``clear_ms`` (clearing the target) and ``draw_ms`` (splat pass) are then the passes' own times."""

    sort_ms: float = 0.0
    upload_ms: float = 0.0
    project_ms: float = 0.0
    choose_ms: float = 0.0
    clear_ms: float = 0.0
    draw_ms: float = 0.0
    sorted: bool = False
    drawn: int = 0
    primitive: str = ""


class SplatRenderer:
    """Draws a Gaussian set with moderngl; see the module docstring for the passes.

    Args:
        ctx: a moderngl context (a window's or a headless EGL one), GL >= 3.3.
        primitive: ``"auto"`` (on a software rasteriser, point sprites when every projected splat fits the
            point size limit and a cost model fitted on llvmpipe expects them to be cheaper; else, and on a
            GPU, quads; both exact), ``"quads"`` (an oriented rectangle per Gaussian) or
            ``"points"`` (point sprites always; splats over the limit are clipped).
        compositing: ``"auto"`` (``fetch`` where the driver has framebuffer fetch, else ``blend``),
            ``"fetch"`` (raises :class:`~viewer.gl.caps.UnsupportedGL` without it) or ``"blend"``;
            :attr:`compositing` holds the path taken.
        color_dtype: ``"nu2"`` (16-bit normalized: the viewer; colour clamped at 1 at every step, which
            changes nothing a display shows, as that clamps the sum), ``"f4"`` (float32: unclamped values,
            tests) or ``"f2"`` (half float; slower than both on llvmpipe).
        near, far: camera-z culling planes in metres, as in :func:`particlesplat.render`.
        caps: the context's capabilities to assume (default: probed); smaller limits than the
            context's emulate a smaller driver.
        sort_device: where the depth sort runs (:mod:`viewer.gl.depth_sort`): ``"auto"`` (a CUDA GPU where
            torch sees one, else numpy), ``"cpu"`` or ``"cuda"``.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        *,
        primitive: str = "auto",
        compositing: Compositing = "auto",
        color_dtype: ColorDtype = "nu2",
        near: float = 0.01,
        far: float = 1e10,
        caps: GLCaps | None = None,
        sort_device: SortDevice = "auto",
    ) -> None:
        if primitive not in PRIMITIVES:
            raise ValueError(f"primitive must be one of {PRIMITIVES}, got {primitive!r}")
        if color_dtype not in COLOR_DTYPES:
            raise ValueError(f"color_dtype must be one of {COLOR_DTYPES}, got {color_dtype!r}")
        self.ctx = ctx
        self.caps = caps if caps is not None else probe(ctx)
        self.compositing = self.caps.compositing(compositing)
        self.primitive = primitive
        self.color_dtype = color_dtype
        self.near, self.far = near, far
        self._point_max_radius = point_max_radius(self.caps)
        mode = {"COMPOSITE_FETCH": 1} if self.compositing == "fetch" else {}
        # a normalized colour target ([0, 1]): fetch holds T as 0.5 + 0.5 T (0.5 T once stopped); blend holds the
        # colour over COLOR_SCALE (GL clamps a fragment's output to [0, 1] before blending into such a target)
        normalized = color_dtype.startswith("n")
        self._unorm_t = self.compositing == "fetch" and normalized
        self._color_scale = COLOR_SCALE if self.compositing == "blend" and normalized else 1.0
        encode: dict[str, str | int] = {"UNORM_T": 1} if self._unorm_t else {}
        if self._color_scale != 1.0:
            encode["COLOR_SCALE"] = repr(self._color_scale)
        self._projects: dict[int, moderngl.Program] = {}  # projection program per SH coefficient count
        # programs per primitive kind and role ("splat", or the id pass with 1 or 8 attachments)
        self._progs: dict[str, dict[str | int, moderngl.Program]] = {}
        # ``auto`` weighs points against quads at each sort only on a software rasteriser (its cost model is
        # llvmpipe's, and choosing reads the projection back); a GPU draws quads at least as fast
        self._weigh_primitives = primitive == "auto" and self.caps.software
        kinds = ("quads", "points") if self._weigh_primitives else ("quads",) if primitive == "auto" else (primitive,)
        for kind in kinds:
            shape = {"QUADS": 1} if kind == "quads" else {}
            vert = load_shader("splat.vert", {"MAX_KEYED": MAX_KEYED, "SPLAT_MARGIN": repr(SPLAT_MARGIN), **shape})
            progs: dict[str | int, moderngl.Program] = {
                "splat": ctx.program(
                    vertex_shader=vert, fragment_shader=load_shader("splat.frag", {**mode, **encode, **shape})
                )
            }
            for n in (1, ID_ATTACHMENTS):
                progs[n] = ctx.program(
                    vertex_shader=vert,
                    fragment_shader=load_shader("splat.frag", {**mode, "ID_PASS": 1, "ATTACH": n, **shape}),
                )
            self._progs[kind] = progs
        self.kind = "quads" if primitive == "auto" else primitive  # the primitive of the current sort
        coverage = {} if self.compositing == "fetch" else {"COVERAGE_ALPHA": 1}
        self._blit = Blit(ctx, {**coverage, **encode})  # the last pass: the render into the window
        self._project_vaos: dict[int, moderngl.VertexArray] = {}
        # data
        self._packed = np.zeros((0, texels_for(1), 4), np.float32)
        self.row = row_for(texels_for(1), self.caps.max_texture_size)  # Gaussians per texture row
        self._means = np.zeros((0, 3), np.float32)
        self._opacity = np.zeros(0, np.float32)
        self._owner = np.zeros(0, np.int64)
        self._groups: dict[int, tuple[int, int]] = {}
        self._data_tex: moderngl.Texture | None = None
        self._proj_tex: list[moderngl.Texture] = []
        self._proj_fbo: moderngl.Framebuffer | None = None
        self._data_version = 0
        # filter and sort
        self._visible_owners: np.ndarray | None = None
        self._min_opacity = 0.0
        self._visible_idx = np.zeros(0, np.int64)
        self._sorter = DepthSorter(resolve_sort_device(sort_device))
        self._filter_version = 0
        self._index_buf: moderngl.Buffer | None = None
        self._order_tex: moderngl.Texture | None = None
        self._vaos: dict[tuple[str, str | int], moderngl.VertexArray] = {}
        self._drawn = 0
        self._key: tuple | None = None  # (view, data, filter) of the current sort + projection
        # targets
        self._color_tex: moderngl.Texture | None = None
        self._color_fbo: moderngl.Framebuffer | None = None
        self._mask_tex: moderngl.Texture | None = None
        self._mask_fbo: moderngl.Framebuffer | None = None
        self._id_tex: list[moderngl.Texture] = []
        self._id_fbo: moderngl.Framebuffer | None = None
        self.size = (0, 0)

    # ------------------------------------------------------------------ data
    @property
    def num(self) -> int:
        """Number of Gaussians held (before filtering)."""
        return self._means.shape[0]

    @property
    def visible_count(self) -> int:
        """Gaussians passing the owner and opacity filter."""
        return int(self._visible_idx.shape[0])

    @property
    def sort_backend(self) -> str:
        """Where the depth sort runs: ``numpy`` (CPU) or ``torch cuda``."""
        return "numpy" if self._sorter.device is None else f"torch {self._sorter.device.type}"

    @property
    def renderer_string(self) -> str:
        """``GL_RENDERER / GL_VERSION`` of the context."""
        return self.caps.renderer

    def set_gaussians(self, gaussians: Gaussians) -> None:
        """Replace all Gaussians (full upload). Gaussians are regrouped by owner internally."""
        owner = gaussians.owner.detach().cpu().numpy()
        order = np.argsort(owner, kind="stable")
        packed = pack_gaussians(gaussians)[order]
        self._set_packed(packed, owner[order])

    def _set_packed(self, packed: np.ndarray, owner: np.ndarray) -> None:
        """packed: (N, texels, 4) float32 grouped by owner; owner: (N,) int64 -> upload all rows."""
        n, texels = packed.shape[0], packed.shape[1]
        row = row_for(texels, self.caps.max_texture_size)
        rows = max(1, math.ceil(n / row))
        if 2 * rows > self.caps.max_texture_size:  # (the order texture holds 2 rows per data row)
            raise ValueError(
                f"{n:,} Gaussians with {texels - 4} SH coefficients exceed this GL driver's "
                f"texture size ({self.caps.max_texture_size}; {self.caps.renderer})"
            )
        self._packed = packed
        self._owner = owner
        self._means = np.ascontiguousarray(packed[:, 0, :3])
        self._opacity = np.ascontiguousarray(packed[:, 0, 3])
        owners, starts, counts = np.unique(owner, return_index=True, return_counts=True)
        self._groups = {int(o): (int(s), int(c)) for o, s, c in zip(owners, starts, counts, strict=False)}
        self.row = row
        if self._data_tex is None or self._data_tex.size != (row * texels, rows):
            for t in [self._data_tex, *self._proj_tex]:
                if t is not None:
                    t.release()
            if self._proj_fbo is not None:
                self._proj_fbo.release()
            self._data_tex = self.ctx.texture((row * texels, rows), 4, dtype="f4")
            self._data_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._proj_tex = [self.ctx.texture((row, rows), 4, dtype="f4") for _ in range(3)]
            self._proj_fbo = self.ctx.framebuffer(color_attachments=self._proj_tex)
        self._write_rows(0, rows)
        self._data_version += 1
        self._refilter()

    def _write_rows(self, r0: int, r1: int) -> None:
        """Upload texture rows [r0, r1) from the packed array."""
        texels, row = self._packed.shape[1], self.row
        block = np.zeros(((r1 - r0) * row, texels, 4), np.float32)
        part = self._packed[r0 * row : r1 * row]
        block[: part.shape[0]] = part
        _made(self._data_tex, "data texture").write(block.tobytes(), viewport=(0, r0, row * texels, r1 - r0))

    def replace_owner(self, owner: int, gaussians: Gaussians) -> None:
        """Replace the Gaussians of one owner; uploads only its rows when the count is unchanged."""
        if (gaussians.owner != owner).any():
            raise ValueError(f"replace_owner({owner}): all Gaussians must have owner {owner}")
        packed = pack_gaussians(gaussians, self._packed.shape[1])
        start, count = self._groups.get(owner, (self.num, 0))
        if count == packed.shape[0] and packed.shape[1] == self._packed.shape[1] and count > 0:
            self._packed[start : start + count] = packed
            self._means[start : start + count] = packed[:, 0, :3]
            self._opacity[start : start + count] = packed[:, 0, 3]
            self._write_rows(start // self.row, (start + count - 1) // self.row + 1)
            self._data_version += 1
            self._refilter()
            return
        keep = self._owner != owner
        held = self._packed
        if packed.shape[1] > held.shape[1]:
            held = np.zeros((self.num, packed.shape[1], 4), np.float32)
            held[:, : self._packed.shape[1]] = self._packed
        all_packed = np.concatenate([held[keep], packed])
        all_owner = np.concatenate([self._owner[keep], np.full(packed.shape[0], owner, np.int64)])
        order = np.argsort(all_owner, kind="stable")
        self._set_packed(all_packed[order], all_owner[order])

    def set_filter(self, visible_owners: np.ndarray | list[int] | None = None, min_opacity: float = 0.0) -> None:
        """Draw only Gaussians whose owner is in ``visible_owners`` (None = all; -1 = background)
        and whose opacity is >= ``min_opacity``."""
        owners = None if visible_owners is None else np.asarray(sorted(set(int(o) for o in visible_owners)), np.int64)
        same = (owners is None and self._visible_owners is None) or (
            owners is not None and self._visible_owners is not None and np.array_equal(owners, self._visible_owners)
        )
        if same and min_opacity == self._min_opacity:
            return
        self._visible_owners, self._min_opacity = owners, float(min_opacity)
        self._refilter()

    def _refilter(self) -> None:
        mask = self._opacity >= self._min_opacity if self._min_opacity > 0 else np.ones(self.num, bool)
        if self._visible_owners is not None:
            mask &= np.isin(self._owner, self._visible_owners)
        self._visible_idx = np.flatnonzero(mask)
        self._sorter.set_points(self._means[self._visible_idx], self._visible_idx)
        self._filter_version += 1

    # ------------------------------------------------------------------ targets
    def _ensure_targets(self, width: int, height: int) -> None:
        if self.size == (width, height):
            return
        for obj in [self._color_fbo, self._color_tex, self._mask_fbo, self._mask_tex, self._id_fbo, *self._id_tex]:
            if obj is not None:
                obj.release()
        self._color_tex = self.ctx.texture((width, height), 4, dtype=self.color_dtype)
        self._color_fbo = self.ctx.framebuffer(color_attachments=[self._color_tex])
        self._mask_tex = self.ctx.texture((width, height), 4, dtype="f4")
        self._mask_fbo = self.ctx.framebuffer(color_attachments=[self._mask_tex])
        self._id_tex, self._id_fbo = [], None
        self.size = (width, height)

    def _ensure_id_targets(self) -> None:
        if self._id_fbo is None:
            self._id_tex = [self.ctx.texture(self.size, 4, dtype="f4") for _ in range(ID_ATTACHMENTS)]
            self._id_fbo = self.ctx.framebuffer(color_attachments=self._id_tex)

    # ------------------------------------------------------------------ passes
    def _prepare(self, camera: Camera, times: FrameTimes, profile: bool = False) -> dict[str, tuple]:
        """Global sort and projection pass, only when the view, the data or the filter changed (``profile``:
        bracket the GPU work with ``glFinish`` to time it)."""
        uni = camera_uniforms(camera)
        self._ensure_targets(camera.width, camera.height)
        key = (uni["w2c"], uni["intr"], uni["size"], self._data_version, self._filter_version)
        if key == self._key:
            return uni
        t0 = time.perf_counter()
        w2c = np.asarray(uni["w2c"], np.float64).reshape(4, 4).T
        order = self._sorter.order(w2c[2], self.near, self.far)
        t1 = time.perf_counter()
        self._upload_order(order)
        t2 = time.perf_counter()
        if profile:
            self.ctx.finish()
        t2 = time.perf_counter()
        times.sort_ms, times.upload_ms, times.sorted = (t1 - t0) * 1e3, (t2 - t1) * 1e3, True
        if self._drawn:
            k = self._sh_bases()
            if k not in self._projects:
                self._projects[k] = self.ctx.program(
                    vertex_shader=load_shader("fullscreen.vert"),
                    fragment_shader=load_shader("project.frag", {"SH_BASES": k}),
                )
                self._project_vaos[k] = self.ctx.vertex_array(self._projects[k], [])
            p = self._projects[k]
            p["gaussians"] = 0
            p["order"] = 1
            p["num"] = self._drawn
            p["row"] = self.row
            p["texels"] = self._packed.shape[1]
            for name in ("w2c", "cam_center", "intr", "lim"):
                if name in p:  # cam_center is unused (optimised out) for SH degree 0
                    p[name] = uni[name]
            p["near_far"] = (self.near, self.far)
            p["dilation"] = DILATION
            _made(self._data_tex, "data texture").use(0)
            _made(self._order_tex, "order texture").use(1)
            _made(self._proj_fbo, "projection target").use()
            self.ctx.disable(moderngl.BLEND)
            self.ctx.viewport = (0, 0, self.row, math.ceil(self._drawn / self.row))
            self._project_vaos[k].render(moderngl.TRIANGLE_STRIP, vertices=4)
            if profile:
                self.ctx.finish()
        t3 = time.perf_counter()
        if self._weigh_primitives:
            self.kind = self._cheaper_primitive()
        times.project_ms, times.choose_ms = (t3 - t2) * 1e3, (time.perf_counter() - t3) * 1e3
        self._key = key
        return uni

    def projected_splats(self) -> np.ndarray:
        """(drawn, 4) of the last projection, front to back: centre u, v and the major and minor radius of the
        alpha >= ALPHA_MIN ellipse (pixels; radius 0 = culled). Reads the projection texture back."""
        if not self._drawn:
            return np.zeros((0, 4), np.float32)
        raw = _made(self._proj_fbo, "projection target").read(
            viewport=(0, 0, self.row, math.ceil(self._drawn / self.row)), components=4, attachment=0, dtype="f4"
        )
        return np.frombuffer(raw, np.float32).reshape(-1, 4)[: self._drawn]

    def _radii(self) -> np.ndarray:
        """(drawn, 2) major and minor radii (pixels) of the projected splats, 0 if culled."""
        return self.projected_splats()[:, 2:4]

    def _cheaper_primitive(self) -> str:
        """Point sprites if every splat fits one (exact: :func:`point_max_radius`, and the guard-band
        viewport within the driver's limit) and the cost model expects them to be faster than quads
        for these splats, else quads."""
        w, h = self.size
        vw, vh = self.caps.max_viewport
        if w + 2 * POINT_GUARD > vw or h + 2 * POINT_GUARD > vh:
            return "quads"
        r = self._radii()
        live = r[:, 0] > 0
        if not live.any():
            return "quads"
        major, minor = 2.0 * (r[live, 0] + SPLAT_MARGIN), 2.0 * (r[live, 1] + SPLAT_MARGIN)
        if float(r[live, 0].max()) > self._point_max_radius:
            return "quads"
        n = int(live.sum())
        points = POINT_COST[0] * n + POINT_COST[1] * float((major * major).sum())
        quads = QUAD_COST[0] * n + QUAD_COST[1] * float((major * minor).sum())
        return "points" if points < quads else "quads"

    def _sh_bases(self) -> int:
        """SH coefficients per channel held in the data texture (one texel each after the first 4)."""
        return self._packed.shape[1] - 4

    def _upload_order(self, order: np.ndarray) -> None:
        """Upload the sorted Gaussian indices (M,) int32 to the order texture read by the projection
        pass; make sure the static quad element buffer is long enough."""
        n, row = order.shape[0], self.row
        self._drawn = n
        rows = max(1, math.ceil(n / row))
        if self._order_tex is None or self._order_tex.height < rows or self._order_tex.width != row:
            if self._order_tex is not None:
                self._order_tex.release()
            self._order_tex = self.ctx.texture((row, 2 * rows), 1, dtype="i4")
            self._order_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        if n:
            block = np.zeros(rows * row, np.int32)
            block[:n] = order
            self._order_tex.write(block.tobytes(), viewport=(0, 0, row, rows))
        if "quads" in self._progs and (self._index_buf is None or self._index_buf.size < 24 * max(n, 1)):
            self._release_vaos(also_buffer=True)
            cap = max(2 * n, 1024)
            corners = np.array([0, 1, 2, 2, 1, 3], np.uint32)
            elems = (4 * np.arange(cap, dtype=np.uint32)[:, None] + corners).reshape(-1)
            self._index_buf = self.ctx.buffer(elems.tobytes())

    def _release_vaos(self, also_buffer: bool = False) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos = {}
        if also_buffer and self._index_buf is not None:
            self._index_buf.release()
            self._index_buf = None

    def _draw(
        self, role: str | int, uni: dict, color_mode: int = 0, owner_base: int = 0, owner_key: np.ndarray | None = None
    ) -> None:
        """Draw the sorted splats with the program of ``role`` ("splat", or the id pass with 1 or
        8 attachments, whose first owner is ``owner_base``) into the bound framebuffer; ``owner_key``
        (MAX_KEYED,) is the colour key per owner of colour mode 2 (None: leave the uniform as it is)."""
        prog = self._progs[self.kind][role]
        if "owner_base" in prog:
            prog["owner_base"] = owner_base
        self.bind_projection(prog, uni, color_mode)
        if "owner_key" in prog and owner_key is not None:
            uniform = prog["owner_key"]
            if isinstance(uniform, moderngl.Uniform):
                uniform.write(owner_key.tobytes())
        if not self._drawn:
            return
        if self.compositing == "blend":  # front to back: dst += (1 - dst alpha) src, alpha = 1 - T
            self.ctx.enable(moderngl.BLEND)
            self.ctx.blend_equation = moderngl.FUNC_ADD, moderngl.FUNC_ADD
            self.ctx.blend_func = moderngl.ONE_MINUS_DST_ALPHA, moderngl.ONE
        else:
            self.ctx.disable(moderngl.BLEND)
        try:
            self._draw_splats(prog, role)
        finally:
            self.ctx.disable(moderngl.BLEND)

    def bind_projection(self, prog: moderngl.Program, uni: dict, color_mode: int = 0) -> None:
        """Bind the projection pass's textures (centres, conics, colours) and the per-frame uniforms a splat
        program reads (``row``, ``size``, ``color_mode``)."""
        for i, t in enumerate(self._proj_tex):
            t.use(i)
        for i, name in enumerate(("center_tex", "conic_tex", "color_tex")):
            if name in prog:
                prog[name] = i
        prog["row"] = self.row
        prog["size"] = uni["size"]
        if "color_mode" in prog:
            prog["color_mode"] = color_mode

    def _draw_splats(self, prog: moderngl.Program, role: str | int) -> None:
        """Issue the draw call of the current primitive kind."""
        kind = self.kind
        if (kind, role) not in self._vaos:
            self._vaos[(kind, role)] = (
                self.ctx.vertex_array(prog, [], index_buffer=self._index_buf, index_element_size=4)
                if kind == "quads"
                else self.ctx.vertex_array(prog, [])
            )
        vao = self._vaos[(kind, role)]
        if kind == "quads":
            vao.render(moderngl.TRIANGLES, vertices=6 * self._drawn)
            return
        w, h = self.size
        prog["guard"] = float(POINT_GUARD)
        self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
        self.ctx.viewport = (-POINT_GUARD, -POINT_GUARD, w + 2 * POINT_GUARD, h + 2 * POINT_GUARD)
        vao.render(moderngl.POINTS, vertices=self._drawn)
        self.ctx.viewport = (0, 0, w, h)

    def _clear(self, fbo: moderngl.Framebuffer) -> None:
        """Clear a compositing target: no colour, T = 1 (alpha 1 for fetch, coverage 0 for blend)."""
        fbo.clear(0.0, 0.0, 0.0, 1.0 if self.compositing == "fetch" else 0.0)

    def _alpha(self, raw_a: np.ndarray, encoded: bool = False) -> np.ndarray:
        """Alpha (1 - T) from a compositing target's alpha channel (T, negated once a pixel stopped,
        for fetch; 1 - T for blend; ``encoded``: the normalized colour target's fetch T, 0.5 + 0.5 T and
        0.5 T once stopped)."""
        if encoded:
            return 1.0 - np.where(raw_a > 0.5, 2.0 * raw_a - 1.0, 2.0 * raw_a)
        return 1.0 - np.abs(raw_a) if self.compositing == "fetch" else raw_a.copy()

    def render(
        self,
        camera: Camera,
        *,
        color_mode: int = 0,
        objects: Sequence[int] | None = None,
        finish: bool = False,
        profile: bool = False,
    ) -> FrameTimes:
        """Render into the offscreen colour target (premultiplied rgb, alpha) at the camera's size.

        color_mode: 0 = SH colour, 1 = a colour per owner (segmentation view), 2 = a colour per object:
        owner k < MAX_KEYED is drawn in the colour of owner ``objects[k]`` (its object's label); owners
        from MAX_KEYED on keep their own colour.
        """
        key = None
        if color_mode == 2:  # the colour keys are uploaded only for the mode that reads them
            key = np.arange(MAX_KEYED, dtype=np.float32)
            head = np.asarray(objects if objects is not None else [], np.float32)[:MAX_KEYED]
            key[: len(head)] = head
        times = FrameTimes()
        uni = self._prepare(camera, times, profile)
        t0 = time.perf_counter()
        fbo = _made(self._color_fbo, "colour target")
        fbo.use()
        self._clear(fbo)
        if profile:
            self.ctx.finish()
        times.clear_ms = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        self._draw("splat", uni, color_mode, owner_key=key)
        if finish or profile:
            self.ctx.finish()
        times.draw_ms = (time.perf_counter() - t0) * 1e3
        times.drawn = self._drawn
        times.primitive = self.kind
        return times

    def render_mask(self, camera: Camera, owner: int) -> None:
        """Render the weight sum T alpha of ``owner`` into the mask target (channel r)."""
        uni = self._prepare(camera, FrameTimes())
        fbo = _made(self._mask_fbo, "mask target")
        fbo.use()
        self._clear(fbo)
        self._draw(1, uni, owner_base=owner)

    def owner_weights(
        self, camera: Camera, num_owners: int, region: tuple[int, int, int, int] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per-owner weights sum_i T_i alpha_i for owners -1 (background) .. num_owners-1.

        region: (x, y, w, h) in image pixels (y down), default the whole image.
        Returns weights (num_owners + 1, h, w) (index 0 = background) and alpha (h, w).
        """
        uni = self._prepare(camera, FrameTimes())
        self._ensure_id_targets()
        width, height = self.size
        x, y, w, h = region if region is not None else (0, 0, width, height)
        gl_y = height - (y + h)
        total = num_owners + 1
        weights = np.zeros((total, h, w), np.float32)
        alpha = np.zeros((h, w), np.float32)
        id_fbo = _made(self._id_fbo, "id target")
        for base in range(-1, num_owners, OWNERS_PER_ID_PASS):
            id_fbo.use()
            self.ctx.scissor = (x, gl_y, w, h)
            self._clear(id_fbo)
            self._draw(ID_ATTACHMENTS, uni, owner_base=base)
            self.ctx.scissor = None
            for i in range(len(self._id_tex)):
                first = base + 1 + 3 * i  # row of weights for owner base + 3 i
                if first >= total:
                    break
                raw = np.frombuffer(
                    id_fbo.read(viewport=(x, gl_y, w, h), components=4, attachment=i, dtype="f4"), np.float32
                ).reshape(h, w, 4)[::-1]
                n = min(3, total - first)
                weights[first : first + n] = np.moveaxis(raw[..., :n], -1, 0)
                if i == 0:
                    alpha = self._alpha(raw[..., 3])
        return weights, alpha

    def segmentation(self, camera: Camera, num_owners: int) -> np.ndarray:
        """(H, W) int64 dominant owner per pixel: argmax over owners of sum T alpha, -1 where the
        background weight plus the empty remainder (1 - alpha) is at least as large (the rule of
        ``RenderResult.segmentation``)."""
        weights, alpha = self.owner_weights(camera, num_owners)
        return segmentation_from_weights(weights, alpha)

    def splat_area(self) -> float:
        """Pixels covered by the splat rectangles (or point squares) of the last projection, summed
        (a diagnostic of the fill work; reads the projection texture back)."""
        r = self._radii()
        r = r[r[:, 0] > 0]
        minor = r[:, 0] if self.kind == "points" else r[:, 1]
        return float((4.0 * (r[:, 0] + SPLAT_MARGIN) * (minor + SPLAT_MARGIN)).sum())

    # ------------------------------------------------------------------ output
    def read_rgba(self) -> np.ndarray:
        """The last render: (H, W, 4) float32 premultiplied rgb and alpha, image rows top down."""
        w, h = self.size
        raw = np.frombuffer(_made(self._color_fbo, "colour target").read(components=4, dtype="f4"), np.float32).reshape(
            h, w, 4
        )[::-1]
        out = raw.copy()
        out[..., :3] *= self._color_scale
        out[..., 3] = self._alpha(raw[..., 3], self._unorm_t)
        return out

    def read_rgb(self, background: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0)) -> np.ndarray:
        """The last render composited over ``background``, a colour or an (H, W, 3) image: (H, W, 3) float32."""
        rgba = self.read_rgba()
        return rgba[..., :3] + (1.0 - rgba[..., 3:]) * np.asarray(background, np.float32)

    def set_support_map(self, support_map: np.ndarray | None) -> None:
        """The scene's support map behind the Gaussians (:meth:`viewer.gl.blit.Blit.set_support_map`): (N, N, 4)
        RGB and support share; None: none."""
        self._blit.set_support_map(support_map)

    def blit(
        self,
        viewport: tuple[int, int, int, int],
        background: tuple[float, float, float],
        mask_color: tuple[float, float, float] | None = None,
        support_camera: Camera | None = None,
    ) -> None:
        """Draw the last render over ``background`` into the bound framebuffer's ``viewport``
        (x, y, w, h in GL pixels); with ``mask_color``, tint the last :meth:`render_mask`. With ``support_camera``
        (the last render's camera) and a :meth:`set_support_map`, over the support map where a pixel's ray meets
        it (:class:`viewer.gl.blit.Blit`)."""
        mask = None if mask_color is None else (_made(self._mask_tex, "mask target"), mask_color)
        self._blit.draw(viewport, background, _made(self._color_tex, "colour target"), mask, support_camera)

    def release(self) -> None:
        """Free the GL objects."""
        objs = [
            self._data_tex,
            *self._proj_tex,
            self._proj_fbo,
            self._index_buf,
            self._order_tex,
            *self._vaos.values(),
            self._color_fbo,
            self._color_tex,
            self._mask_fbo,
            self._mask_tex,
            self._id_fbo,
            *self._id_tex,
            *self._project_vaos.values(),
            *self._projects.values(),
            *(p for progs in self._progs.values() for p in progs.values()),
        ]
        for obj in objs:
            if obj is not None:
                obj.release()
        self._blit.release()


def segmentation_from_weights(weights: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """weights: (P + 1, H, W) with the background first; alpha: (H, W) -> (H, W) int64 owner,
    -1 where background weight + (1 - alpha) >= the best owner's weight."""
    owners = weights[1:]
    if owners.shape[0] == 0:
        return np.full(alpha.shape, -1, np.int64)
    best = owners.argmax(0)
    best_w = np.take_along_axis(owners, best[None], 0)[0]
    background = weights[0] + (1.0 - alpha)
    return np.where(best_w > background, best, -1).astype(np.int64)
