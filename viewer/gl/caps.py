"""What the viewer may use on the current OpenGL context, probed at run time.

The viewer needs only core GL 3.3. Everything beyond it is chosen here from the context:

* compositing: with ``GL_EXT_shader_framebuffer_fetch`` (Mesa llvmpipe and Intel, Apple) the splat
  pass composites in the fragment shader, exactly like :func:`particlesplat.render`; without it
  (NVIDIA, AMD) it uses fixed-function blending with the coverage ``1 - T`` kept in destination alpha;
* point sprites: core GL 3.3 guarantees sprites of 1 px only; their largest size is read from
  ``GL_POINT_SIZE_RANGE`` and the widened viewport of the point pass from ``GL_MAX_VIEWPORT_DIMS``;
* texture sizes: core GL 3.3 guarantees 1024 texels a side; the renderer sizes its data textures
  from ``GL_MAX_TEXTURE_SIZE``.

The shaders' numeric rules come from the library's constants (:func:`shader_constants`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

Compositing = Literal["auto", "fetch", "blend"]
COMPOSITING: tuple[str, ...] = get_args(Compositing)
FETCH_EXTENSION = "GL_EXT_shader_framebuffer_fetch"
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swiftshader", "software rasterizer")

COMPOSITING_HELP = (
    "splat compositing: fetch = in the fragment shader with GL_EXT_shader_framebuffer_fetch "
    "(exactly the torch renderer's rules), blend = fixed-function blending, core GL 3.3 only (no "
    "early stop at T <= 1e-4: pixels differ by <= 1e-4), auto = fetch where the driver has it "
    "(default: %(default)s)"
)


class UnsupportedGL(RuntimeError):
    """The GL context lacks what a forced option needs."""


@dataclass(frozen=True)
class GLCaps:
    """Capabilities of one GL context.

    Attributes:
        renderer: ``GL_RENDERER / GL_VERSION``.
        framebuffer_fetch: ``GL_EXT_shader_framebuffer_fetch`` is exposed.
        max_point_size: largest point sprite side, pixels (``GL_POINT_SIZE_RANGE``).
        max_texture_size: largest texture side, texels.
        max_viewport: largest viewport (width, height), pixels.
    """

    renderer: str
    framebuffer_fetch: bool
    max_point_size: float
    max_texture_size: int
    max_viewport: tuple[int, int]

    @property
    def software(self) -> bool:
        """A CPU rasteriser (llvmpipe, softpipe, SwiftShader), where fragments cost like vertices."""
        name = self.renderer.lower()
        return any(k in name for k in SOFTWARE_RENDERERS)

    def compositing(self, requested: Compositing) -> Literal["fetch", "blend"]:
        """The compositing path for ``requested``: ``auto`` takes fetch where it exists. Raises
        :class:`UnsupportedGL` for ``fetch`` on a driver without the extension."""
        if requested not in COMPOSITING:
            raise ValueError(f"compositing must be one of {COMPOSITING}, got {requested!r}")
        if requested == "fetch" and not self.framebuffer_fetch:
            raise UnsupportedGL(
                f"--compositing fetch: this OpenGL driver ({self.renderer}) lacks {FETCH_EXTENSION}; "
                f"use --compositing auto or blend"
            )
        if requested == "auto":
            return "fetch" if self.framebuffer_fetch else "blend"
        return requested


def probe(ctx) -> GLCaps:
    """Read the capabilities of a moderngl context (GL >= 3.3)."""
    info = ctx.info
    if ctx.version_code < 330:
        raise UnsupportedGL(
            f"OpenGL 3.3 or newer is needed, this context is {info['GL_VERSION']} ({info['GL_RENDERER']})"
        )
    point = info.get("GL_POINT_SIZE_RANGE") or (1.0, 1.0)
    viewport = info.get("GL_MAX_VIEWPORT_DIMS") or (4096, 4096)
    return GLCaps(
        renderer=f"{info['GL_RENDERER']} / {info['GL_VERSION']}",
        framebuffer_fetch=FETCH_EXTENSION in ctx.extensions,
        max_point_size=float(point[1]),
        max_texture_size=int(info.get("GL_MAX_TEXTURE_SIZE") or 1024),
        max_viewport=(int(viewport[0]), int(viewport[1])),
    )


def shader_constants() -> dict[str, str]:
    """The compositing rules of :func:`particlesplat.render` as GLSL ``#define`` values: footprint
    alpha >= ALPHA_MIN, alpha clamped at ALPHA_MAX, a pixel stops before the splat that would take its
    transmittance to <= T_MIN. (The renderer's modules load torch: imported here, so the viewer's options, which
    name the compositing paths, are answered without it.)"""
    from particlesplat.rendering.projection import ALPHA_MAX, ALPHA_MIN
    from particlesplat.rendering.rasterize import T_MIN

    return {"ALPHA_MIN": repr(float(ALPHA_MIN)), "ALPHA_MAX": repr(float(ALPHA_MAX)), "T_MIN": repr(float(T_MIN))}
