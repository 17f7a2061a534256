"""``particlesplat bench viewer``: GL renderer frame times (sort / upload / draw) at 1024x768 for
random Gaussian sets and the demo scene, and the edit -> frame latency of dragging a particle.

Runs on a headless EGL context (the window presents the same offscreen render with one blit,
under 1 ms on Xvfb). Every frame turns the camera, so every frame re-sorts and re-projects.
With several compositing paths (``--compositing fetch,blend``) each case is measured on every
path, the paths taking turns frame by frame, and the table ends with their frame-time ratios. A naive
splatter (:mod:`viewer.naive`: instanced 3-sigma quads, covariance and SH per corner, full resolution
always) takes its turns on the same cameras as the baseline; every row reports its PSNR against the
torch renderer at full resolution.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .state import DEFAULT_PRUNE

if TYPE_CHECKING:  # the GL modules load only when the benchmark runs
    from particlesplat.camera import Camera
    from particlesplat.viewpoints import View

    from .gl_renderer import SplatRenderer
    from .naive import NaiveSplatter
    from .session import SceneSession

DEFAULT_SIZES = (20000, 100000)


@dataclass
class Row:
    name: str
    gaussians: int
    sort_ms: float
    upload_ms: float
    draw_ms: float
    frame_ms: float
    area_mpx: float = 0.0
    moving_ms: float = 0.0
    primitive: str = ""
    floor_ms: float = float("nan")
    compositing: str = ""
    psnr_db: float = float("nan")


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
    data = np.stack([s[:, 0], s[:, 1], 2.0 * s[:, 2] + 1.0], 1).astype(np.float32)
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
    p.add_argument("--width", type=int, default=1024, help="frame width in pixels (default: %(default)s)")
    p.add_argument("--height", type=int, default=768, help="frame height in pixels (default: %(default)s)")
    p.add_argument("--frames", type=int, default=30, help="timed frames per case (default: %(default)s)")
    p.add_argument(
        "--primitive",
        choices=("auto", "quads", "points"),
        default="auto",
        help="splat primitive (default: %(default)s, as the viewer)",
    )
    p.add_argument(
        "--compositing",
        default="auto",
        help="compositing paths, comma-separated, each of auto (fetch where the driver has it), fetch, "
        "blend; several are measured side by side (default: %(default)s, as the viewer)",
    )
    p.add_argument(
        "--moving-scale",
        type=float,
        default=0.5,
        help="render scale the viewer uses while the camera moves (default: %(default)s)",
    )
    p.add_argument(
        "--pixel-scale",
        type=float,
        default=0.005,
        help="random Gaussians' scale at 20k, in units of the cube half-size (default: %(default)s)",
    )
    p.add_argument("--checkpoint", help="model for the demo scene and the edit latency (default: shipped)")
    p.add_argument("--scene", help="scene folder (default: the first demo scene)")
    p.add_argument("--no-scene", action="store_true", help="skip the demo scene and the edit latency")
    p.add_argument("--no-baseline", action="store_true", help="skip the naive splatter")
    p.add_argument(
        "--no-psnr",
        action="store_true",
        help="skip the PSNR against the torch renderer (it takes ~10-25 s a case on 2 cores)",
    )
    return p


def _time_frames(renderers: list[SplatRenderer], cameras: list[Camera]) -> list[Row]:
    """Median timings over ``cameras`` (the first frame is a warm-up) for each renderer. The renderers
    take turns on every camera (in alternating order), so a change of load on a shared machine
    falls on all of them alike."""
    times = [([], [], [], []) for _ in renderers]  # sort, upload, draw, total
    for r in renderers:
        r.render(cameras[0], finish=True)  # warm-up: shader compile, first upload
    for k, cam in enumerate(cameras[1:]):
        turn = list(enumerate(renderers))
        for i, r in turn[::-1] if k % 2 else turn:
            t0 = time.perf_counter()
            ft = r.render(cam, finish=True)
            total = (time.perf_counter() - t0) * 1e3
            for series, v in zip(times[i], (ft.sort_ms, ft.upload_ms, ft.draw_ms, total), strict=True):
                series.append(v)
    med = lambda v: float(np.median(v))  # noqa: E731
    return [
        Row(
            "",
            r.visible_count,
            med(sort),
            med(upload),
            med(draw),
            med(total),
            r.splat_area() / 1e6,
            primitive=r.kind,
            compositing=r.compositing,
        )
        for r, (sort, upload, draw, total) in zip(renderers, times, strict=True)
    ]


def _case(
    renderers: list[SplatRenderer], view: View, args: argparse.Namespace, baseline: NaiveSplatter | None = None
) -> list[Row]:
    """Full-size frames, then the frame time at the viewer's moving render scale, for each renderer;
    the baseline (last row) takes its turns at full size and moves at full size (its moving time is
    its frame time)."""
    rows = _time_frames(
        [*renderers, *([baseline] if baseline else [])], orbit_cameras(view, args.width, args.height, args.frames)
    )
    w, h = round(args.width * args.moving_scale), round(args.height * args.moving_scale)
    for row, moving in zip(rows, _time_frames(renderers, orbit_cameras(view, w, h, args.frames)), strict=False):
        row.moving_ms = moving.frame_ms
    if baseline:
        rows[-1].moving_ms = rows[-1].frame_ms
    return rows


def psnr_against_torch(renderers: list, g, camera: Camera) -> list[float]:
    """PSNR (dB) of each renderer's image of ``camera`` against :func:`particlesplat.render` (over black)."""
    import torch

    from particlesplat import render

    with torch.no_grad():
        ref = render(g, camera).rgb.numpy().astype(np.float64)
    out = []
    for r in renderers:
        r.render(camera, finish=True)
        mse = float(np.mean((r.read_rgb().astype(np.float64) - ref) ** 2))
        out.append(float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse))
    return out


def orbit_cameras(view: View, width: int, height: int, frames: int) -> list[Camera]:
    """``frames + 1`` cameras turning 1 degree per frame about ``view``."""
    from dataclasses import replace

    from particlesplat.viewpoints import Look

    lk = view.look
    return [
        replace(view, look=Look(lk.azimuth + i, lk.elevation, lk.distance)).camera(width, height)
        for i in range(frames + 1)
    ]


def edit_latency(
    renderer: SplatRenderer, session: SceneSession, view: View, width: int, height: int, steps: int = 20
) -> float:
    """Median ms from a z_p change of one particle to the finished frame (decode, upload, sort, draw)."""
    from .scene_view import SceneView
    from .state import ViewState

    sv = SceneView(renderer)
    state = ViewState()
    cam = view.camera(width, height)
    sv.draw(session, state, cam, finish=True)
    index = max(range(session.num_particles), key=lambda i: float(session.particles.z_t[i, 0]))
    times = []
    for k in range(steps):
        zp = session.value(index, "z_p")
        t0 = time.perf_counter()
        session.set_attribute(index, "z_p", [zp[0] + (0.01 if k % 2 == 0 else -0.01), zp[1]], gesture="bench")
        sv.draw(session, state, cam, finish=True)
        times.append((time.perf_counter() - t0) * 1e3)
    session.end_gesture()
    return float(np.median(times))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import moderngl
    import torch

    torch.set_num_threads(1)  # as the viewer: tiny per-particle decodes, llvmpipe owns the cores

    from particlesplat.viewpoints import default_view

    from .gl_caps import COMPOSITING, UnsupportedGL
    from .gl_renderer import SplatRenderer
    from .naive import NaiveSplatter
    from .random_gaussians import random_gaussians

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
    ctx = moderngl.create_standalone_context(backend="egl")
    renderers: dict[str, SplatRenderer] = {}
    try:
        for v in requested:
            r = SplatRenderer(ctx, primitive=args.primitive, compositing=v, color_dtype="f4")
            if r.compositing in renderers:
                r.release()
            else:
                renderers[r.compositing] = r
    except UnsupportedGL as e:
        print(f"bench viewer: {e}", file=sys.stderr)
        return 2
    renderer = next(iter(renderers.values()))
    baseline = None if args.no_baseline else NaiveSplatter(ctx)
    drawers = [*renderers.values(), *([baseline] if baseline else [])]
    load0 = os.getloadavg()
    rows: list[Row] = []
    for n in sizes:
        g = random_gaussians(n, seed=0, pixel_scale=args.pixel_scale)
        for r in drawers:
            r.set_gaussians(g)
        case = _case(list(renderers.values()), default_view(None, g), args, baseline)
        for row, renderer in zip(case, renderers.values(), strict=False):
            # re-project at full size (the last frames were at the moving scale), then the floor of those splats
            renderer.render(default_view(None, g).camera(args.width, args.height), finish=True)
            if renderer.kind == "points":
                row.floor_ms = sprite_floor_ms(ctx, renderer, args.width, args.height, args.frames)
        for row in case:
            row.name = f"random {n // 1000}k" if n % 1000 == 0 else f"random {n}"
        if not args.no_psnr:
            for row, db in zip(
                case, psnr_against_torch(drawers, g, default_view(None, g).camera(args.width, args.height)), strict=True
            ):
                row.psnr_db = db
        rows += case
    latency: dict[str, tuple[float, float]] = {}
    failure = None
    if not args.no_scene:
        from particlesplat.encode_scene import load_model_scene

        from .session import SceneSession

        try:
            model, enc, _ = load_model_scene(args.checkpoint, args.scene)
        except (OSError, ValueError) as e:  # reported after the random-set table, exit status 1
            failure = f"demo scene not measured: {e}"
    if not args.no_scene and failure is None:
        scene = enc.path
        session = SceneSession(model, enc)
        g = session.gaussians()
        view = default_view(enc.all_cameras)
        for r in drawers:
            r.set_gaussians(g)
            r.set_filter(min_opacity=DEFAULT_PRUNE)  # what the viewer draws by default
        case = _case(list(renderers.values()), view, args, baseline)
        for row in case:
            row.name = f"demo scene ({os.path.basename(str(scene))}, opacity >= {DEFAULT_PRUNE:g})"
        if not args.no_psnr:
            for row, db in zip(
                case,
                psnr_against_torch(
                    drawers, g.subset(g.opacities >= DEFAULT_PRUNE), view.camera(args.width, args.height)
                ),
                strict=True,
            ):
                row.psnr_db = db
        rows += case
        for path, renderer in renderers.items():
            latency[path] = (
                edit_latency(renderer, session, view, args.width, args.height),
                edit_latency(
                    renderer,
                    session,
                    view,
                    round(args.width * args.moving_scale),
                    round(args.height * args.moving_scale),
                ),
            )
    load1 = os.getloadavg()
    print(f"GL renderer: {renderer.renderer_string}")
    print(
        f"{args.width}x{args.height}, {args.primitive}, median of {args.frames} frames, camera turning 1 deg/frame "
        f"(every frame re-sorts); load average {load0[0]:.1f} -> {load1[0]:.1f} on {os.cpu_count()} CPUs"
    )
    print()
    num = lambda v, f: "-" if v != v else format(v, f)  # noqa: E731  (NaN: not measured)
    print(
        f"| scene | Gaussians | compositing | primitive | splat area Mpx | sort ms | upload ms | draw ms | "
        f"frame ms | frame ms at {args.moving_scale:g} scale (moving) | sprite floor ms | PSNR dB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r.name} | {r.gaussians:,} | {r.compositing} | {r.primitive} | {num(r.area_mpx, '.1f')} | "
            f"{r.sort_ms:.1f} | {r.upload_ms:.2f} | {r.draw_ms:.1f} | {r.frame_ms:.1f} | {r.moving_ms:.1f} | "
            f"{num(r.floor_ms, '.1f')} | {num(r.psnr_db, '.1f')} |"
        )
    print(
        "\nsprite floor: the same point sprites (centres, sides) drawn with a constant colour and no blending, "
        "the least a point-sprite splatter pays here before shading and compositing"
    )
    if baseline:
        print(
            "naive: the baseline (instanced 3-sigma quads, covariance and SH per corner, back-to-front blending); "
            "it moves at full resolution"
        )
    if not args.no_psnr:
        print("PSNR: the first camera at full size against particlesplat.render (over black)")
    paths = list(renderers)
    per_case = len(paths) + (1 if baseline else 0)
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
                    f"{o.compositing} {o.frame_ms / base.frame_ms:.2f}x still, "
                    f"{o.moving_ms / base.moving_ms:.2f}x moving"
                    for o in others
                )
            )
    if baseline:
        print("\nframe time over the naive baseline's (its full-resolution frame; same cameras, same run):")
        for i in range(0, len(rows), per_case):
            ours, naive = rows[i : i + len(paths)], rows[i + len(paths)]
            print(
                f"- {naive.name}: "
                + "; ".join(
                    f"{o.compositing} {o.frame_ms / naive.frame_ms:.2f}x still, "
                    f"{o.moving_ms / naive.frame_ms:.2f}x moving"
                    for o in ours
                )
            )
    for path, (full, moving) in latency.items():
        print(
            f"\nedit -> frame latency, {path} (drag one particle's z_p: decode it, upload its rows, sort, project, "
            f"draw): {full:.1f} ms at {args.width}x{args.height}, {moving:.1f} ms at the moving scale "
            f"{args.moving_scale:g} (what a drag in the viewer renders)"
        )
    for r in drawers:
        r.release()
    ctx.release()
    if failure:
        print(f"\n{failure}", file=sys.stderr)
        return 1
    return 0
