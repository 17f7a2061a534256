"""``particlesplat bench viewer``: the viewer's GL renderer against limacv/GaussianSplattingViewer, in one run.

Random Gaussian sets (SH degree 3) seen with the peer's default camera distance and field of view (3 m, 90°)
and scene folders (``--scenes``: the shipped model's decode, drawn as the viewer draws it) at 1280x720 on a
headless EGL context. Our frame is what the viewer does for a new camera: the render into its offscreen target
and the blit that presents it (over the background, upscaled for moving frames) into a window-sized RGBA8
framebuffer, up to ``glFinish``; the peer draws straight into one.
Every frame turns the camera by 1°, so every frame re-sorts and re-projects. Each compositing path
(``--compositing fetch,blend``) and, with ``--peer DIR``, the peer (:mod:`viewer.bench.peer`: a clone of
limacv/GaussianSplattingViewer driven from its own modules, fed the same .ply and cameras, its draw timed
with ``glFinish``) take turns on every camera, in alternating order, so load on a shared machine falls on
all of them alike. Still frames are full size; moving frames are what a drag shows: ours at the viewer's
moving render scale, the peer at full size (it has no other). The table gives median times, the ratios
(peer over ours: above 1 = ours faster) and the PSNR of every drawer against :func:`particlesplat.render`
at full resolution.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..state import DEFAULT_PRUNE

if TYPE_CHECKING:  # the GL modules load only when the benchmark runs
    from particlesplat.core.camera import Camera
    from particlesplat.core.viewpoints import View

    from ..gl.renderer import FrameTimes, SplatRenderer
    from ..session import EditableScene

DEFAULT_SIZES = (20000, 100000)
RANDOM_DISTANCE, RANDOM_FOV = 3.0, 90.0  # the peer's default camera
RANDOM_ELEVATION = 25.0


@dataclass
class Row:
    name: str
    gaussians: int
    sort_ms: float
    upload_ms: float
    project_ms: float
    draw_ms: float
    frame_ms: float
    area_mpx: float = 0.0
    moving_ms: float = 0.0
    primitive: str = ""
    floor_ms: float = float("nan")
    compositing: str = ""
    psnr_db: float = float("nan")
    blit_ms: float = 0.0
    extra: dict = field(default_factory=dict)


FLOOR_VERTEX = """#version 330
in vec3 in_splat;  // centre u, v (pixels, rows downward), sprite side (pixels)
uniform vec2 size;
void main() {
    gl_Position = vec4(in_splat.x / size.x * 2.0 - 1.0, 1.0 - in_splat.y / size.y * 2.0, 0.0, 1.0);
    gl_PointSize = in_splat.z;
}
"""
FLOOR_FRAGMENT = """#version 330
out vec4 o;
void main() { o = vec4(0.5); }
"""


def sprite_floor_ms(ctx, renderer: SplatRenderer, width: int, height: int, frames: int) -> float:
    """Median ms to draw the last frame's point sprites (same centres and sides) with a constant colour and
    no blending: what any point-sprite splatter pays on this GL before its shading and compositing."""
    import moderngl

    s = renderer.projected_splats()
    s = s[s[:, 2] > 0]
    if not len(s):
        return 0.0
    from ..gl.renderer import SPLAT_MARGIN

    data = np.stack([s[:, 0], s[:, 1], 2.0 * (s[:, 2] + SPLAT_MARGIN)], 1).astype(np.float32)
    prog = ctx.program(vertex_shader=FLOOR_VERTEX, fragment_shader=FLOOR_FRAGMENT)
    prog["size"] = (float(width), float(height))
    buf = ctx.buffer(data.tobytes())
    vao = ctx.vertex_array(prog, [(buf, "3f", "in_splat")])
    fbo = ctx.simple_framebuffer((width, height), components=4, dtype="f4")
    ctx.enable(moderngl.PROGRAM_POINT_SIZE)
    ctx.disable(moderngl.BLEND)
    times = []
    for _ in range(frames + 1):
        fbo.use()
        fbo.clear()
        t0 = time.perf_counter()
        vao.render(moderngl.POINTS)
        ctx.finish()
        times.append((time.perf_counter() - t0) * 1e3)
    for obj in (vao, buf, fbo, prog):
        obj.release()
    return float(np.median(times[1:]))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="particlesplat bench viewer", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--sizes",
        default=",".join(str(s) for s in DEFAULT_SIZES),
        help="random Gaussian counts, comma-separated (default: %(default)s)",
    )
    p.add_argument("--width", type=int, default=1280, help="frame width in pixels (default: %(default)s)")
    p.add_argument("--height", type=int, default=720, help="frame height in pixels (default: %(default)s)")
    p.add_argument("--frames", type=int, default=20, help="timed frames per case (default: %(default)s)")
    p.add_argument(
        "--primitive",
        choices=("auto", "quads", "points"),
        default="auto",
        help="splat primitive (default: %(default)s, as the viewer)",
    )
    p.add_argument(
        "--compositing",
        default="fetch,blend",
        help="compositing paths, comma-separated, each of auto (fetch where the driver has it), fetch, "
        "blend; several are measured side by side (default: %(default)s)",
    )
    p.add_argument(
        "--moving-scale",
        type=float,
        default=None,
        help="render scale of ours while the camera moves (default: the viewer's)",
    )
    p.add_argument(
        "--pixel-scale",
        type=float,
        default=0.005,
        help="random Gaussians' scale at 20k, in units of the cube half-size (default: %(default)s)",
    )
    p.add_argument("--checkpoint", help="model for the scenes and the edit latency (default: shipped)")
    p.add_argument(
        "--scenes",
        default=None,
        help="scene folders, comma-separated, each encoded with the model and drawn as the viewer draws it "
        "(opacity >= the viewer's prune threshold); default: the first demo scene",
    )
    p.add_argument("--no-scene", action="store_true", help="skip the scenes and the edit latency")
    p.add_argument(
        "--peer",
        metavar="DIR",
        help="a clone of limacv/GaussianSplattingViewer to measure alongside (see viewer/bench/peer.py)",
    )
    p.add_argument(
        "--peer-path",
        action="append",
        default=[],
        metavar="DIR",
        help="extra import path for the peer's requirements (PyOpenGL, PyGLM, plyfile), e.g. a venv's "
        "site-packages; repeatable",
    )
    p.add_argument(
        "--profile",
        action="store_true",
        help="instead: the time of every pass (viewer/bench/profile.py), same cases and options",
    )
    p.add_argument(
        "--no-psnr",
        action="store_true",
        help="skip the PSNR against the torch renderer (it takes ~10-60 s a case on 2 cores)",
    )
    return p


EGL: dict[str, Any] = {"backend": "egl"}  # a headless context (moderngl's stub types its settings oddly)
BACKGROUND = (0.1, 0.1, 0.1)  # what our frames are presented over (the viewer's default is dark)


def _frame(r, camera: Camera, window) -> tuple[FrameTimes, float]:
    """One frame of drawer ``r``: ours renders and presents with its blit into ``window`` (a window-sized RGBA8
    framebuffer), the peer draws (into its own RGBA8 framebuffer), both up to ``glFinish`` (ours also before the
    blit, to time it alone: llvmpipe does not overlap the two). Returns the drawer's FrameTimes and the ms of the
    blit (0 for the peer)."""
    if r.compositing == "limacv":
        return r.render(camera, finish=True), 0.0
    ft = r.render(camera, finish=True)
    t0 = time.perf_counter()
    window.use()
    r.blit((0, 0, *window.size), BACKGROUND)
    r.ctx.finish()
    return ft, (time.perf_counter() - t0) * 1e3


def _time_frames(drawers: list, cameras: list[Camera], window, full: list[Camera] | None = None) -> list[Row]:
    """Median timings over ``cameras`` (the first frame is a warm-up) for each drawer, a frame presented into
    ``window`` (:func:`_frame`). The drawers take turns on every camera (in alternating order), so a change of
    load on a shared machine falls on all of them alike. ``full``: the same poses at full size, drawn by drawers
    without a render scale (the peer)."""
    times: list[tuple[list[float], ...]] = [([], [], [], [], [], []) for _ in drawers]  # sort, upload, project,
    # draw, total, blit
    pick = lambda r, k: (full or cameras)[k] if r.compositing == "limacv" else cameras[k]  # noqa: E731
    for r in drawers:
        _frame(r, pick(r, 0), window)  # warm-up: shader compile, first upload
    for k in range(1, len(cameras)):
        turn = list(enumerate(drawers))
        for i, r in turn[::-1] if k % 2 else turn:
            t0 = time.perf_counter()
            ft, blit = _frame(r, pick(r, k), window)
            total = (time.perf_counter() - t0) * 1e3
            values = (ft.sort_ms, ft.upload_ms, ft.project_ms + ft.choose_ms, ft.draw_ms, total, blit)
            for series, v in zip(times[i], values, strict=True):
                series.append(v)
    med = lambda v: float(np.median(v))  # noqa: E731
    return [
        Row(
            "",
            r.visible_count,
            sort_ms=med(series[0]),
            upload_ms=med(series[1]),
            project_ms=med(series[2]),
            draw_ms=med(series[3]),
            frame_ms=med(series[4]),
            blit_ms=med(series[5]),
            area_mpx=r.splat_area() / 1e6,
            primitive=r.kind,
            compositing=r.compositing,
        )
        for r, series in zip(drawers, times, strict=True)
    ]


def _case(renderers: list[SplatRenderer], peer, view: View, args: argparse.Namespace, window) -> list[Row]:
    """Full-size frames, then the moving frames (ours at the moving render scale, the peer at full size),
    for each drawer, all taking turns on the same camera poses, ours presented into ``window``."""
    drawers = [*renderers, *([peer] if peer else [])]
    full = orbit_cameras(view, args.width, args.height, args.frames)
    rows = _time_frames(drawers, full, window)
    w, h = round(args.width * args.moving_scale), round(args.height * args.moving_scale)
    moving = _time_frames(drawers, orbit_cameras(view, w, h, args.frames), window, full)
    for row, m in zip(rows, moving, strict=True):
        row.moving_ms = m.frame_ms
        row.extra["moving_blit_ms"] = m.blit_ms
    return rows


def psnr_against_torch(renderers: list, g, camera: Camera) -> list[float]:
    """PSNR (dB) of each renderer's image of ``camera`` against :func:`particlesplat.render` (over black), both
    clamped to [0, 1] as a display shows them (the viewer's colour target and the peer's RGBA8 hold no more)."""
    import torch

    from particlesplat import render

    with torch.no_grad():
        ref = np.clip(render(g, camera).rgb.numpy().astype(np.float64), 0.0, 1.0)
    out = []
    for r in renderers:
        r.render(camera, finish=True)
        mse = float(np.mean((np.clip(r.read_rgb().astype(np.float64), 0.0, 1.0) - ref) ** 2))
        out.append(float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse))
    return out


def orbit_cameras(view: View, width: int, height: int, frames: int) -> list[Camera]:
    """``frames + 1`` cameras turning 1 degree per frame about ``view``."""
    from dataclasses import replace

    from particlesplat.core.viewpoints import Look

    lk = view.look
    return [
        replace(view, look=Look(lk.azimuth + i, lk.elevation, lk.distance)).camera(width, height)
        for i in range(frames + 1)
    ]


def edit_latency(
    renderer: SplatRenderer, session: EditableScene, view: View, width: int, height: int, steps: int = 20
) -> float:
    """Median ms from a z_p change of one particle to the finished frame (decode, upload, sort, draw)."""
    from ..scene_view import SceneView
    from ..state import ViewState

    sv = SceneView(renderer)
    state = ViewState()
    cam = view.camera(width, height)
    sv.draw(session, state, cam, finish=True)
    editor = session.editor
    index = max(range(editor.num_particles), key=lambda i: float(editor.particles.z_t[i, 0]))
    times = []
    for k in range(steps):
        zp = editor.value(index, "z_p")
        t0 = time.perf_counter()
        editor.set_attribute(index, "z_p", [zp[0] + (0.01 if k % 2 == 0 else -0.01), zp[1]], gesture="bench")
        sv.draw(session, state, cam, finish=True)
        times.append((time.perf_counter() - t0) * 1e3)
    editor.end_gesture()
    return float(np.median(times))


def _scenes(args: argparse.Namespace) -> list[str | None]:
    if args.no_scene:
        return []
    if args.scenes is None:
        return [None]  # the first demo scene
    return [v.strip() for v in args.scenes.split(",") if v.strip()]


def _print_table(rows: list[Row], args: argparse.Namespace, paths: list[str], peer) -> None:
    num = lambda v, f: "-" if v != v else format(v, f)  # noqa: E731  (NaN: not measured)
    print(
        f"| scene | Gaussians | compositing | primitive | splat area Mpx | sort ms | upload ms | "
        f"frame ms (still) | frame ms moving ({args.moving_scale:g} scale; limacv full) | blit ms (still / moving) | "
        f"sprite floor ms | PSNR dB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        blit = "-" if r.compositing == "limacv" else f"{r.blit_ms:.1f} / {r.extra.get('moving_blit_ms', 0.0):.1f}"
        print(
            f"| {r.name} | {r.gaussians:,} | {r.compositing} | {r.primitive} | {num(r.area_mpx, '.1f')} | "
            f"{r.sort_ms:.1f} | {r.upload_ms:.2f} | {r.frame_ms:.1f} | {r.moving_ms:.1f} | {blit} | "
            f"{num(r.floor_ms, '.1f')} | {num(r.psnr_db, '.1f')} |"
        )
    print(
        "\nframe: sort, upload, projection pass, clear, splat pass and the blit presenting it into a "
        f"{args.width}x{args.height} RGBA8 framebuffer (upscaled when moving), up to glFinish (per pass: "
        "particlesplat bench viewer --profile); sprite floor: the same point sprites (centres, sides) drawn with "
        "a constant colour and no blending, the least a point-sprite splatter pays here before shading and compositing"
    )
    if peer:
        print(
            "limacv: limacv/GaussianSplattingViewer's OpenGLRenderer (instanced 3-sigma quads, covariance and SH per "
            "corner, numpy argsort, back-to-front blending into RGBA8); sort ms = its update_camera_* and "
            "sort_and_update; it moves at full resolution"
        )
    if not args.no_psnr:
        print("PSNR: the first camera at full size against particlesplat.render (over black, both clamped to [0, 1])")
    per_case = len(paths) + (1 if peer else 0)
    if len(paths) > 1:
        print(
            f"\nframe time ratios, {' / '.join(paths[1:])} over {paths[0]} (same cameras, the paths taking turns "
            f"frame by frame):"
        )
        for i in range(0, len(rows), per_case):
            base, others = rows[i], rows[i + 1 : i + len(paths)]
            print(
                f"- {base.name}: "
                + "; ".join(
                    f"{o.compositing} {o.frame_ms / base.frame_ms:.2f}x still, {o.moving_ms / base.moving_ms:.2f}x "
                    "moving"
                    for o in others
                )
            )
    if peer:
        print(
            "\nlimacv's frame time over ours (above 1: ours faster; same cameras, same run; moving: ours at the "
            "moving scale, limacv at full size):"
        )
        for i in range(0, len(rows), per_case):
            ours, other = rows[i : i + len(paths)], rows[i + len(paths)]
            print(
                f"- {other.name}: "
                + "; ".join(
                    f"{o.compositing} {other.frame_ms / o.frame_ms:.2f}x still, "
                    f"{other.moving_ms / o.moving_ms:.2f}x moving"
                    for o in ours
                )
            )


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    from .peer import PeerError, PeerSplatter, select_egl_platform

    if args.peer:
        select_egl_platform()  # before anything imports PyOpenGL
    import moderngl
    import torch

    torch.set_num_threads(1)  # as the viewer: tiny per-particle decodes, llvmpipe owns the cores

    from particlesplat.core.viewpoints import Look, View, default_view

    from ..gl.caps import COMPOSITING, UnsupportedGL
    from ..gl.renderer import SplatRenderer
    from ..state import ViewState
    from .random_gaussians import random_gaussians

    if args.moving_scale is None:
        args.moving_scale = ViewState().moving_scale
    try:
        sizes = [int(v) for v in args.sizes.split(",") if v.strip()]
    except ValueError:
        print(f"bench viewer: --sizes: expected comma-separated integers, got {args.sizes!r}", file=sys.stderr)
        return 2
    if (
        any(n < 1 for n in sizes)
        or args.frames < 1
        or args.width < 16
        or args.height < 16
        or not (0.0 < args.moving_scale <= 1.0)
    ):
        print(
            "bench viewer: sizes and --frames must be >= 1, --width/--height >= 16, --moving-scale in (0, 1]",
            file=sys.stderr,
        )
        return 2
    requested = [v.strip() for v in args.compositing.split(",") if v.strip()]
    if not requested or any(v not in COMPOSITING for v in requested):
        print(
            f"bench viewer: --compositing: expected a comma-separated list of {', '.join(COMPOSITING)}, "
            f"got {args.compositing!r}",
            file=sys.stderr,
        )
        return 2
    ctx = (
        moderngl.create_standalone_context(require=430, **EGL)
        if args.peer
        else moderngl.create_standalone_context(**EGL)
    )
    renderers: dict[str, SplatRenderer] = {}
    peer = None
    try:
        for v in requested:
            r = SplatRenderer(ctx, primitive=args.primitive, compositing=v)  # the viewer's colour target
            if r.compositing in renderers:
                r.release()
            else:
                renderers[r.compositing] = r
        if args.peer:
            import tempfile

            workdir = tempfile.mkdtemp(prefix="bench-viewer-")
            peer = PeerSplatter(ctx, args.peer, args.peer_path, workdir=workdir)
    except (UnsupportedGL, PeerError) as e:
        print(f"bench viewer: {e}", file=sys.stderr)
        return 2
    renderer = next(iter(renderers.values()))
    window = ctx.simple_framebuffer((args.width, args.height), components=4)  # what our frames are presented into
    drawers: list[Any] = [*renderers.values(), *([peer] if peer else [])]  # ours and the peer: one interface
    load0 = os.getloadavg()
    rows: list[Row] = []

    def measure(name: str, g, view: View) -> list[Row]:
        for r in drawers:
            r.set_gaussians(g)
        case = _case(list(renderers.values()), peer, view, args, window)
        cam = view.camera(args.width, args.height)
        for row, r in zip(case, renderers.values(), strict=False):
            # re-project at full size (the last frames were at the moving scale), then the floor of those splats
            r.render(cam, finish=True)
            if r.kind == "points":
                row.floor_ms = sprite_floor_ms(ctx, r, args.width, args.height, args.frames)
        for row in case:
            row.name = name
        if not args.no_psnr:
            for row, db in zip(case, psnr_against_torch(drawers, g, cam), strict=True):
                row.psnr_db = db
        return case

    for n in sizes:
        g = random_gaussians(n, seed=0, pixel_scale=args.pixel_scale)
        view = View((0.0, 0.0, 0.0), Look(0.0, RANDOM_ELEVATION, RANDOM_DISTANCE), RANDOM_FOV)
        rows += measure(f"random {n // 1000}k" if n % 1000 == 0 else f"random {n}", g, view)
    latency: dict[str, tuple[float, float]] = {}
    failure = None
    for k, scene in enumerate(_scenes(args)):
        from particlesplat.editing.open_scene import load_model_scene

        from ..session import EditableScene

        try:
            model, enc, _ = load_model_scene(args.checkpoint, scene)
        except (OSError, ValueError) as e:  # reported after the table, exit status 1
            failure = f"scene {scene} not measured: {e}"
            continue
        session = EditableScene(model, enc)
        g = session.gaussians()
        g = g.subset(g.opacities >= DEFAULT_PRUNE)  # what the viewer draws by default
        view = default_view(enc.all_cameras)
        rows += measure(f"scene {os.path.basename(str(enc.path))} (opacity >= {DEFAULT_PRUNE:g})", g, view)
        if k == 0:
            for path, r in renderers.items():
                r.set_gaussians(session.gaussians())
                r.set_filter(min_opacity=DEFAULT_PRUNE)
                small = (round(args.width * args.moving_scale), round(args.height * args.moving_scale))
                latency[path] = (
                    edit_latency(r, session, view, args.width, args.height),
                    edit_latency(r, session, view, *small),
                )
                r.set_filter()
    load1 = os.getloadavg()
    print(f"GL renderer: {renderer.renderer_string}; depth sort: {renderer.sort_backend}")
    print(
        f"{args.width}x{args.height}, {args.primitive}, median of {args.frames} frames, camera turning 1 deg/frame "
        f"(every frame re-sorts); load average {load0[0]:.1f} -> {load1[0]:.1f} on {os.cpu_count()} CPUs"
    )
    print()
    _print_table(rows, args, list(renderers), peer)
    for path, (full, moving) in latency.items():
        print(
            f"\nedit -> frame latency, {path} (drag one particle's z_p: decode it, upload its rows, sort, project, "
            f"draw): {full:.1f} ms at {args.width}x{args.height}, {moving:.1f} ms at the moving scale "
            f"{args.moving_scale:g} (what a drag in the viewer renders)"
        )
    for r in drawers:
        r.release()
    window.release()
    ctx.release()
    if failure:
        print(f"\n{failure}", file=sys.stderr)
        return 1
    return 0
