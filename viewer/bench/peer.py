"""Drives limacv/GaussianSplattingViewer's OpenGL renderer (MIT, a plain PyOpenGL splatter) from a clone
given by path, on the benchmark's GL context, cameras and Gaussians. Nothing of the peer is copied here:
its modules (``renderer_ogl``, ``util``, ``util_gau``) are imported from the clone, it reads the same
``.ply`` with its own loader, builds its matrices with its own ``util.Camera``, and draws with its own
``OpenGLRenderer.sort_and_update`` and ``draw``; this module only times them (``glFinish``) and reads the
pixels back.

The peer needs PyOpenGL (the benchmark selects its EGL platform), PyGLM and plyfile (its
requirements.txt); ``peer_paths`` are extra import paths for them (e.g. the site-packages of a venv
holding its requirements), appended after this environment's own.
"""

from __future__ import annotations

import importlib
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from particlesplat.core.camera import Camera

if TYPE_CHECKING:
    import moderngl

REQUIRED = ("renderer_ogl.py", "util.py", "util_gau.py", "shaders/gau_vert.glsl", "shaders/gau_frag.glsl")
SH_BASES = 16  # its .ply reader asserts SH degree 3
GL_VERSION = 430  # its shaders are "#version 430 core" (shader storage buffers)


class PeerError(RuntimeError):
    """The peer clone cannot be used (missing files or modules); the message says what to do."""


def select_egl_platform() -> None:
    """PyOpenGL must talk to the benchmark's EGL context: set before ``OpenGL`` is first imported."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


@contextmanager
def _cwd(path: Path):
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


class PeerSplatter:
    """limacv/GaussianSplattingViewer's ``OpenGLRenderer`` with the benchmark's part of the
    :class:`~viewer.gl.renderer.SplatRenderer` interface (``set_gaussians``, ``render``, ``read_rgb``).

    It draws into an RGBA8 framebuffer of the camera's size (what its window has), cleared to black as
    its main loop does, with the blending its renderer sets up (``SRC_ALPHA, ONE_MINUS_SRC_ALPHA``).
    A frame is what its viewer does for a new camera: ``update_camera_pose``, ``update_camera_intrin``,
    ``sort_and_update`` (numpy argsort, index upload), clear, ``draw`` (instanced 3-sigma quads), and
    ``glFinish``.
    """

    kind = "instanced quads"
    compositing = "limacv"

    def __init__(
        self, ctx, peer_dir: str | os.PathLike, peer_paths: list[str] | None = None, workdir: str = "."
    ) -> None:
        self.ctx = ctx
        self.dir = Path(peer_dir).resolve()
        missing = [f for f in REQUIRED if not (self.dir / f).is_file()]
        if missing:
            raise PeerError(f"--peer {peer_dir}: not a GaussianSplattingViewer clone (missing {', '.join(missing)})")
        if ctx.version_code < GL_VERSION:
            raise PeerError(f"the peer needs OpenGL {GL_VERSION / 100:.1f}; this context has {ctx.version_code}")
        select_egl_platform()
        if str(self.dir) not in sys.path:
            sys.path.insert(0, str(self.dir))
        for p in peer_paths or []:  # after this environment's own packages
            if p not in sys.path:
                sys.path.append(p)
        try:
            with _cwd(self.dir):
                self.util = importlib.import_module("util")
                self.util_gau = importlib.import_module("util_gau")
                self.renderer_ogl = importlib.import_module("renderer_ogl")
        except ImportError as e:
            raise PeerError(
                f"cannot import the peer from {self.dir}: {e} (it needs PyOpenGL, PyGLM and plyfile: "
                "pass --peer-path SITE_PACKAGES of an environment holding its requirements.txt)"
            ) from e
        self.gl = importlib.import_module("OpenGL.GL")
        self.workdir = Path(workdir)
        self.size = (0, 0)
        self._fbo: moderngl.Framebuffer | None = None
        self._renderer: Any = None  # the peer's OpenGLRenderer (its own module: untyped)
        self._camera = None
        self._num = 0

    @property
    def visible_count(self) -> int:
        return self._num

    def set_gaussians(self, g, ply_path: str | os.PathLike | None = None) -> None:
        """Write ``g`` as a 3DGS .ply (or use ``ply_path``, already holding it) and load it with the
        peer's own reader."""
        from particlesplat.formats.ply import write_ply

        path = Path(ply_path) if ply_path else self.workdir / "peer-input.ply"
        if ply_path is None:
            if g.sh.shape[1] < SH_BASES:  # its reader takes SH degree 3 only: zero bands draw the same colour
                pad = g.sh.new_zeros(g.num, SH_BASES - g.sh.shape[1], 3)
                g = replace(g, sh=torch.cat([g.sh, pad], 1))
            write_ply(g, path)
        data = self.util_gau.load_ply(str(path))
        if self._renderer is None:
            with _cwd(self.dir):  # it loads its shaders by relative path
                self._renderer = self.renderer_ogl.OpenGLRenderer(1280, 720)
        self._renderer.update_gaussian_data(data)
        self._renderer.set_scale_modifier(1.0)
        self._renderer.set_render_mod(3)  # its default mode: "SH:0~3"
        self._num = len(data)

    def _peer_camera(self, camera: Camera):
        """The peer's own camera object placed at ``camera`` (eye, target along the view axis, image up,
        vertical field of view, size): its ``get_view_matrix``/``get_project_matrix`` build the matrices."""
        c2w = camera.c2w.detach().double().cpu().numpy()
        cam = self.util.Camera(camera.height, camera.width)
        cam.position = c2w[:3, 3].astype(np.float32)
        cam.target = (c2w[:3, 3] + c2w[:3, 2]).astype(np.float32)
        cam.up = (-c2w[:3, 1]).astype(np.float32)
        cam.fovy = float(np.deg2rad(camera.fov_y))
        cam.znear = 0.01
        return cam

    def render(self, camera: Camera, *, finish: bool = False):
        from viewer.gl.renderer import FrameTimes

        gl = self.gl
        if self._fbo is None or self.size != (camera.width, camera.height):
            if self._fbo is not None:
                self._fbo.release()
            self._fbo = self.ctx.simple_framebuffer((camera.width, camera.height), components=4)
            self.size = (camera.width, camera.height)
        cam = self._peer_camera(camera)
        times = FrameTimes(primitive=self.kind)
        self._fbo.use()
        self.ctx.viewport = (0, 0, camera.width, camera.height)
        for _ in range(16):  # PyOpenGL checks glGetError after each call: drop flags the benchmark's own calls left
            if gl.glGetError() == gl.GL_NO_ERROR:
                break
        t0 = time.perf_counter()
        r = self._renderer
        r.set_render_reso(camera.width, camera.height)
        r.update_camera_pose(cam)
        r.update_camera_intrin(cam)
        r.sort_and_update(cam)
        t1 = time.perf_counter()
        gl.glEnable(gl.GL_BLEND)  # the state its renderer sets once at start-up
        gl.glBlendFunc(gl.GL_SRC_ALPHA, gl.GL_ONE_MINUS_SRC_ALPHA)
        gl.glDisable(gl.GL_CULL_FACE)
        gl.glClearColor(0, 0, 0, 1.0)
        gl.glClear(gl.GL_COLOR_BUFFER_BIT)
        r.draw()
        if finish:
            gl.glFinish()
        t2 = time.perf_counter()
        gl.glDisable(gl.GL_BLEND)
        gl.glBindVertexArray(0)
        gl.glUseProgram(0)
        times.sort_ms = (t1 - t0) * 1e3
        times.draw_ms = (t2 - t1) * 1e3
        times.sorted, times.drawn = True, self._num
        return times

    def splat_area(self) -> float:
        return float("nan")

    def read_rgb(self, background: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """The last frame: (H, W, 3) float32 in [0, 1], image rows top down (drawn over black; a
        background other than black is not supported: the peer blends its colour straight)."""
        w, h = self.size
        if self._fbo is None:
            raise RuntimeError("PeerSplatter.read_rgb: nothing rendered yet")
        raw = np.frombuffer(self._fbo.read(components=3), np.uint8).reshape(h, w, 3)[::-1]
        return raw.astype(np.float32) / 255.0

    def release(self) -> None:
        if self._fbo is not None:
            self._fbo.release()
            self._fbo = None
