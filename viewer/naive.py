"""A naive splatter, the benchmark's baseline: Gaussians drawn the way simple viewers draw them.

One instanced screen-aligned quad per Gaussian with a 3-sigma extent; the 3D covariance, its EWA
projection and the SH colour are evaluated in the vertex shader for every corner (four times per
Gaussian); the Gaussians are sorted back to front on the CPU every frame and composited with
fixed-function ``SRC_ALPHA, ONE_MINUS_SRC_ALPHA`` blending (alpha: ``ONE, ONE_MINUS_SRC_ALPHA``), at full
resolution always. Core GL 3.3.
Its rules differ from :func:`particlesplat.render` (no Jacobian clamp, a 3-sigma cut instead of the
alpha >= 1/255 ellipse, no early stop); the benchmark reports its PSNR against the torch renderer.
"""

from __future__ import annotations

import math
import time

import moderngl
import numpy as np
import torch

from particlesplat.camera import Camera
from particlesplat.gaussians import Gaussians

from .gl_caps import shader_constants
from .gl_renderer import ROW, FrameTimes, camera_uniforms

VERTEX = """
uniform sampler2D data;  // per Gaussian: mean + opacity, quaternion wxyz, scales, SH_BASES SH texels
uniform int texels;
uniform int row;
uniform mat4 w2c;
uniform vec3 cam_center;
uniform vec4 intr;  // fx, fy, cx, cy
uniform vec2 size;
in int gi;  // per instance: the Gaussian, back to front
out vec2 v_d;  // pixel offset from the centre
flat out vec3 v_conic;
flat out vec4 v_color;  // rgb, opacity

const float C0 = 0.28209479177387814;
const float C1 = 0.4886025119029199;
const float C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                             -1.0925484305920792, 0.5462742152960396);
const float C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                             0.3731763325901154, -0.4570457994644658, 1.445305721320277,
                             -0.5900435899266435);

vec4 fetch(int k) {
    return texelFetch(data, ivec2((gi % row) * texels + k, gi / row), 0);
}

void main() {
    vec4 t0 = fetch(0);
    vec3 pc = (w2c * vec4(t0.xyz, 1.0)).xyz;
    vec4 q = normalize(fetch(1));
    vec3 s = fetch(2).xyz;
    float w = q.x, x = q.y, y = q.z, z = q.w;
    mat3 R = mat3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
                  2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
                  2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
    mat3 M = R * mat3(s.x, 0.0, 0.0, 0.0, s.y, 0.0, 0.0, 0.0, s.z);
    mat3 sigma = M * transpose(M);
    mat3 J = mat3(intr.x / pc.z, 0.0, 0.0, 0.0, intr.y / pc.z, 0.0,
                  -intr.x * pc.x / (pc.z * pc.z), -intr.y * pc.y / (pc.z * pc.z), 0.0);
    mat3 T = J * mat3(w2c);
    mat3 cov = T * sigma * transpose(T);
    float a = cov[0][0] + 0.3, b = cov[0][1], c = cov[1][1] + 0.3;
    float det = a * c - b * b;
    if (pc.z <= 0.01 || det <= 0.0) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return;
    }
    float mid = 0.5 * (a + c);
    float radius = ceil(3.0 * sqrt(mid + sqrt(max(mid * mid - det, 0.1))));
    vec2 uv = vec2(intr.x * pc.x / pc.z + intr.z, intr.y * pc.y / pc.z + intr.w);
    vec3 d = normalize(t0.xyz - cam_center);
    float dx = d.x, dy = d.y, dz = d.z;
    vec3 rgb = C0 * fetch(3).rgb;
#if SH_BASES > 1
    rgb += -C1 * dy * fetch(4).rgb + C1 * dz * fetch(5).rgb - C1 * dx * fetch(6).rgb;
#endif
#if SH_BASES > 4
    float xx = dx * dx, yy = dy * dy, z2 = dz * dz;
    rgb += C2[0] * dx * dy * fetch(7).rgb + C2[1] * dy * dz * fetch(8).rgb
         + C2[2] * (2.0 * z2 - xx - yy) * fetch(9).rgb + C2[3] * dx * dz * fetch(10).rgb
         + C2[4] * (xx - yy) * fetch(11).rgb;
#endif
#if SH_BASES > 9
    rgb += C3[0] * dy * (3.0 * xx - yy) * fetch(12).rgb + C3[1] * dx * dy * dz * fetch(13).rgb
         + C3[2] * dy * (4.0 * z2 - xx - yy) * fetch(14).rgb
         + C3[3] * dz * (2.0 * z2 - 3.0 * xx - 3.0 * yy) * fetch(15).rgb
         + C3[4] * dx * (4.0 * z2 - xx - yy) * fetch(16).rgb + C3[5] * dz * (xx - yy) * fetch(17).rgb
         + C3[6] * dx * (xx - 3.0 * yy) * fetch(18).rgb;
#endif
    vec2 corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1)) * 2.0 - 1.0;
    v_d = corner * radius;
    v_conic = vec3(c, -b, a) / det;
    v_color = vec4(max(rgb + 0.5, vec3(0.0)), t0.w);
    vec2 p = uv + v_d;
    gl_Position = vec4(p.x / size.x * 2.0 - 1.0, 1.0 - p.y / size.y * 2.0, 0.0, 1.0);
}
"""

FRAGMENT = """
in vec2 v_d;
flat in vec3 v_conic;
flat in vec4 v_color;
out vec4 o;

void main() {
    float power = -0.5 * (v_conic.x * v_d.x * v_d.x + 2.0 * v_conic.y * v_d.x * v_d.y + v_conic.z * v_d.y * v_d.y);
    if (power > 0.0) discard;
    float alpha = min(ALPHA_MAX, v_color.a * exp(power));
    if (alpha < ALPHA_MIN) discard;
    o = vec4(v_color.rgb, alpha);
}
"""


class NaiveSplatter:
    """The baseline renderer (see the module docstring), with the benchmark's part of the
    :class:`~viewer.gl_renderer.SplatRenderer` interface."""

    kind = "instanced quads"
    compositing = "naive"

    def __init__(self, ctx: moderngl.Context, near: float = 0.01) -> None:
        self.ctx = ctx
        self.near = near
        self.size = (0, 0)
        self._prog: moderngl.Program | None = None
        self._tex: moderngl.Texture | None = None
        self._objs: list = []
        self._vao: moderngl.VertexArray | None = None
        self._index: moderngl.Buffer | None = None
        self._fbo: moderngl.Framebuffer | None = None
        self._means = np.zeros((0, 3), np.float32)
        self._opacity = np.zeros(0, np.float32)
        self._visible = np.zeros(0, np.int64)
        self._drawn = 0

    @property
    def visible_count(self) -> int:
        return int(self._visible.shape[0])

    @property
    def renderer_string(self) -> str:
        return f"{self.ctx.info['GL_RENDERER']} / {self.ctx.info['GL_VERSION']}"

    def set_gaussians(self, g: Gaussians) -> None:
        """Upload the Gaussians (mean, opacity, quaternion, scales, SH) to a data texture."""
        g = g.detach().to("cpu", torch.float32)
        self.release()
        n, k = g.num, g.sh.shape[1]
        texels = 3 + k
        rows = max(1, math.ceil(n / ROW))
        packed = np.zeros((rows * ROW, texels, 4), np.float32)
        packed[:n, 0, :3], packed[:n, 0, 3] = g.means.numpy(), g.opacities.numpy()
        packed[:n, 1] = g.quats.numpy()
        packed[:n, 2, :3] = g.scales.numpy()
        packed[:n, 3:, :3] = g.sh.numpy()
        tex = self.ctx.texture((ROW * texels, rows), 4, packed.tobytes(), dtype="f4")
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        defines = "".join(f"#define {a} {b}\n" for a, b in shader_constants().items())
        prog = self.ctx.program(
            vertex_shader=f"#version 330\n#define SH_BASES {k}\n{VERTEX}",
            fragment_shader=f"#version 330\n{defines}{FRAGMENT}",
        )
        prog["data"], prog["texels"], prog["row"] = 0, texels, ROW
        index = self.ctx.buffer(reserve=max(4 * n, 4))
        self._prog, self._index, self._tex = prog, index, tex
        self._vao = self.ctx.vertex_array(prog, [(index, "1i /i", "gi")])
        self._objs = [self._vao, index, prog, tex]
        self._means, self._opacity = g.means.numpy(), g.opacities.numpy()
        self._visible = np.arange(n)

    def set_filter(self, visible_owners=None, min_opacity: float = 0.0) -> None:
        """Draw only Gaussians with opacity >= ``min_opacity`` (owners are not filtered)."""
        self._visible = np.flatnonzero(self._opacity >= min_opacity)

    def render(self, camera: Camera, *, finish: bool = False) -> FrameTimes:
        """Sort back to front and draw at the camera's size over black."""
        times = FrameTimes(primitive=self.kind)
        uni = camera_uniforms(camera)
        if self.size != (camera.width, camera.height):
            if self._fbo is not None:
                self._fbo.release()
            self._fbo = self.ctx.simple_framebuffer((camera.width, camera.height), components=4, dtype="f4")
            self.size = (camera.width, camera.height)
        t0 = time.perf_counter()
        w2c = np.asarray(uni["w2c"], np.float64).reshape(4, 4).T
        idx = self._visible
        z = self._means[idx] @ w2c[2, :3].astype(np.float32) + np.float32(w2c[2, 3])
        keep = z > self.near
        order = idx[keep][np.argsort(-z[keep], kind="stable")].astype(np.int32)  # back to front
        t1 = time.perf_counter()
        self._index.write(order.tobytes())
        t2 = time.perf_counter()
        for name in ("w2c", "cam_center", "intr", "size"):
            if name in self._prog:
                self._prog[name] = uni[name]
        self._fbo.use()
        self._fbo.clear(0.0, 0.0, 0.0, 0.0)
        self._tex.use(0)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_equation = moderngl.FUNC_ADD
        self.ctx.blend_func = (
            moderngl.SRC_ALPHA,
            moderngl.ONE_MINUS_SRC_ALPHA,
            moderngl.ONE,
            moderngl.ONE_MINUS_SRC_ALPHA,
        )
        if len(order):
            self._vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=len(order))
        self.ctx.disable(moderngl.BLEND)
        if finish:
            self.ctx.finish()
        times.sort_ms, times.upload_ms = (t1 - t0) * 1e3, (t2 - t1) * 1e3
        times.draw_ms = (time.perf_counter() - t2) * 1e3
        times.sorted, times.drawn = True, len(order)
        self._drawn = len(order)
        return times

    def splat_area(self) -> float:
        """Not measured for the baseline (its quads are sized in the vertex shader)."""
        return float("nan")

    def read_rgb(self, background: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """The last render over ``background``: (H, W, 3) float32, image rows top down."""
        w, h = self.size
        raw = np.frombuffer(self._fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)[::-1]
        return raw[..., :3] + (1.0 - raw[..., 3:]) * np.asarray(background, np.float32)

    def release(self) -> None:
        """Free the GL objects of the current set."""
        for obj in self._objs:
            obj.release()
        self._objs = []
