"""``particlesplat bench viewer --profile``: where a frame of the GL renderer goes, pass by pass, on this driver.

Every pass is bracketed by ``glFinish`` (so llvmpipe cannot overlap it with the next; the sum is a little
above the frame time of ``particlesplat bench viewer``), median over frames with the camera turning 1° a
frame (every frame re-sorts and re-projects), for each compositing path, at full size (still) and at the
viewer's moving render scale:

- sort: camera depths and the global front-to-back sort (numpy, one thread)
- upload: the sorted indices into the order texture
- projection: the projection pass (one fragment per Gaussian: EWA covariance, ellipse, SH colour)
- choose: ``auto``'s primitive choice (reads the projected radii back)
- clear: clearing the float compositing target
- splat: the splat pass (vertex work, rasterisation, footprint, compositing); of it ``geometry`` is the
  same primitives drawn with a constant colour, no footprint test and no blending or framebuffer fetch,
  and ``shading + compositing`` the rest
- blit: presenting the render over the background into a window-sized RGBA8 framebuffer (upscaled from the
  moving scale)
- id pick: the id pass on a 1x1 region (what a click runs); id frame: the id pass over the whole frame
  (24 owners a pass: what segmentation views and masks cost)
"""

from __future__ import annotations

import os
import time

import numpy as np

PASSES = ("sort", "upload", "projection", "choose", "clear", "splat", "geometry", "blit", "id pick", "id frame")


def _flat_program(renderer):
    """The renderer's splat program for its current primitive with FLAT_FRAGMENT: geometry only."""
    from ..gl.renderer import MAX_KEYED, SPLAT_MARGIN
    from ..gl.shaders import load_shader

    kind = renderer.kind
    progs = renderer._progs[kind]
    if "flat" not in progs:
        shape = {"QUADS": 1} if kind == "quads" else {}
        vert = load_shader("splat.vert", {"MAX_KEYED": MAX_KEYED, "SPLAT_MARGIN": repr(SPLAT_MARGIN), **shape})
        progs["flat"] = renderer.ctx.program(
            vertex_shader=vert, fragment_shader=load_shader("splat.frag", {"FLAT_FRAGMENT": 1})
        )
    return progs["flat"]


def _geometry_ms(renderer, uni) -> float:
    import moderngl

    prog = _flat_program(renderer)
    renderer.bind_projection(prog, uni)
    renderer._color_fbo.use()
    renderer._clear(renderer._color_fbo)
    renderer.ctx.disable(moderngl.BLEND)
    renderer.ctx.finish()
    t0 = time.perf_counter()
    if renderer._drawn:
        renderer._draw_splats(prog, "flat")
    renderer.ctx.finish()
    return (time.perf_counter() - t0) * 1e3


def profile_case(ctx, renderer, cameras, window: tuple[int, int], num_owners: int) -> dict[str, float]:
    """Median ms per pass over ``cameras`` (the first is a warm-up) for one renderer."""
    from ..gl.packing import camera_uniforms

    win = ctx.simple_framebuffer(window, components=4)
    series: dict[str, list[float]] = {k: [] for k in PASSES}
    for k, cam in enumerate(cameras):
        ft = renderer.render(cam, profile=True)
        uni = camera_uniforms(cam)
        geometry = _geometry_ms(renderer, uni)
        renderer.render(cam, finish=True)  # (same camera: no sort; the colour target again for the blit)
        win.use()
        ctx.finish()
        t0 = time.perf_counter()
        renderer.blit((0, 0, *window), (0.1, 0.1, 0.1))
        ctx.finish()
        blit = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        renderer.owner_weights(cam, num_owners, region=(cam.width // 2, cam.height // 2, 1, 1))
        pick = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        renderer.owner_weights(cam, min(num_owners, 23))  # one id pass over the frame
        id_frame = (time.perf_counter() - t0) * 1e3
        if k == 0:
            continue
        values = (ft.sort_ms, ft.upload_ms, ft.project_ms, ft.choose_ms, ft.clear_ms, ft.draw_ms, geometry, blit)
        for name, v in zip(PASSES, (*values, pick, id_frame), strict=True):
            series[name].append(v)
    win.release()
    return {k: float(np.median(v)) for k, v in series.items()}


def main(argv: list[str] | None = None) -> int:
    from .run import EGL, RANDOM_DISTANCE, RANDOM_ELEVATION, RANDOM_FOV, build_parser, orbit_cameras

    p = build_parser()
    p.prog = "particlesplat bench viewer --profile"
    args = p.parse_args(argv)
    import moderngl
    import torch

    torch.set_num_threads(1)
    from particlesplat.core.viewpoints import Look, View, default_view

    from ..gl.renderer import SplatRenderer
    from ..state import DEFAULT_PRUNE, ViewState
    from .random_gaussians import random_gaussians

    moving = args.moving_scale or ViewState().moving_scale
    paths = [v.strip() for v in args.compositing.split(",") if v.strip()]
    ctx = moderngl.create_standalone_context(**EGL)
    renderers = [SplatRenderer(ctx, primitive=args.primitive, compositing=v) for v in paths]  # the viewer's target
    cases = []
    for n in [int(v) for v in args.sizes.split(",") if v.strip()]:
        g = random_gaussians(n, seed=0, pixel_scale=args.pixel_scale)
        view = View((0.0, 0.0, 0.0), Look(0.0, RANDOM_ELEVATION, RANDOM_DISTANCE), RANDOM_FOV)
        cases.append((f"random {n // 1000}k" if n % 1000 == 0 else f"random {n}", g, view, 8))
    if not args.no_scene:
        from particlesplat.editing.open_scene import load_model_scene

        from ..session import EditableScene

        scenes = [None] if args.scenes is None else [v.strip() for v in args.scenes.split(",") if v.strip()]
        for scene in scenes:
            model, enc, _ = load_model_scene(args.checkpoint, scene)
            g = EditableScene(model, enc).gaussians()
            g = g.subset(g.opacities >= DEFAULT_PRUNE)
            name = f"scene {os.path.basename(str(enc.path))}"
            cases.append((name, g, default_view(enc.all_cameras), int(g.owner.max()) + 1))
    load0 = os.getloadavg()
    rows = []
    for name, g, view, owners in cases:
        for r in renderers:
            r.set_gaussians(g)
        for scale in (1.0, moving):
            w, h = round(args.width * scale), round(args.height * scale)
            cams = orbit_cameras(view, w, h, args.frames)
            for r in renderers:  # the paths one after the other (each needs its own target and id pass)
                ms = profile_case(ctx, r, cams, (args.width, args.height), owners)
                rows.append((name, g.num, r.compositing, r.kind, scale, ms))
    load1 = os.getloadavg()
    print(f"GL renderer: {renderers[0].renderer_string}; depth sort: {renderers[0].sort_backend}")
    print(
        f"{args.width}x{args.height} window, median of {args.frames} frames a row, every pass bracketed by "
        f"glFinish; load average {load0[0]:.1f} -> {load1[0]:.1f} on {os.cpu_count()} CPUs\n"
    )
    print(
        "| case | Gaussians | compositing | primitive | scale | sort | upload | projection | choose | clear | splat "
        "(geometry + shading/compositing) | blit | sum | id pick | id frame |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, n, comp, kind, scale, ms in rows:
        total = sum(ms[k] for k in ("sort", "upload", "projection", "choose", "clear", "splat", "blit"))
        print(
            f"| {name} | {n:,} | {comp} | {kind} | {scale:g} | {ms['sort']:.1f} | {ms['upload']:.2f} | "
            f"{ms['projection']:.1f} | {ms['choose']:.1f} | {ms['clear']:.1f} | {ms['splat']:.1f} "
            f"({ms['geometry']:.1f} + {ms['splat'] - ms['geometry']:.1f}) | {ms['blit']:.1f} | {total:.1f} | "
            f"{ms['id pick']:.1f} | {ms['id frame']:.1f} |"
        )
    for r in renderers:
        r.release()
    ctx.release()
    return 0
