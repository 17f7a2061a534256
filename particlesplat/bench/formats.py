"""``particlesplat bench formats``: size and fidelity of each Gaussian file format on a scene.

The scene (a model scene, the first demo scene by default, or ``--ply FILE``) is written as ``.ply`` and rendered
at ``--width`` x ``--height`` from its default view (the view ``particlesplat render --ply`` takes); each format
is then written and read back here and its render compared with that one (PSNR, dB). With ``--splat-transform
CMD`` (e.g. ``"npx @playcanvas/splat-transform"``) two more columns: each file we write converted by it to
``.ply`` and read here, and each file it writes from our ``.ply`` (SPZ as version 3) read here. An object bundle
(``--by object``, or by particle for a ``.ply``) is merged back and compared too.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from particlesplat.bench.render import machine_line
from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import OptionError, one_line
from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.splat_files import FORMATS, read_gaussians

THEIR_WRITES = {".compressed.ply": (), ".spz": ("--spz-version", "3"), ".sog": ()}  # splat-transform writes these


def _psnr(g: Gaussians, camera, want: torch.Tensor, background) -> float:
    from particlesplat.analysis.metrics import psnr
    from particlesplat.rendering.api import render

    with torch.no_grad():
        return psnr(render(g, camera, background=background).rgb.clamp(0, 1), want)


def _convert(cmd: list[str], src: Path, dst: Path, *options: str) -> str | None:
    """Run splat-transform ``src`` -> ``dst``; None when it worked, else its error (one line)."""
    try:
        run = subprocess.run(
            [*cmd, "-q", "-w", "-g", "cpu", *options, str(src), str(dst)], capture_output=True, text=True, timeout=600
        )
    except (OSError, subprocess.TimeoutExpired) as e:
        return one_line(e, 200)
    return None if run.returncode == 0 and dst.is_file() else one_line(run.stderr or f"exit {run.returncode}", 200)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="particlesplat bench formats", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scene", help="scene folder; none = the first demo scene")
    parser.add_argument("--ply", help="a Gaussian file instead of a model scene")
    parser.add_argument("--checkpoint", help="model checkpoint; none = the shipped model of the scene's family")
    parser.add_argument("--context", help="context frames, e.g. 4,16; none = the default")
    parser.add_argument("--width", type=int, default=320, help="render width in pixels (default 320)")
    parser.add_argument("--height", type=int, default=240, help="render height in pixels (default 240)")
    parser.add_argument("--splat-transform", metavar="CMD", help="also convert through this splat-transform command")
    parser.add_argument("--json", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    if not (1 <= args.width <= 4096 and 1 <= args.height <= 4096):
        raise OptionError(f"--width/--height must be in [1, 4096], got {args.width}x{args.height}")
    from particlesplat.core.outputs import guard_outputs
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.editing.open_scene import demo_scenes

    scene = None if args.ply else args.scene or next(iter(demo_scenes()), None)  # what is read, defaults included
    checkpoint = None if args.ply else args.checkpoint or default_checkpoint(scene)
    guard_outputs([("--json", args.json)], [("--ply", args.ply), ("--scene", scene), ("--checkpoint", checkpoint)])
    from particlesplat.core.viewpoints import default_view, scene_background

    arrays, source = None, args.ply
    if args.ply:
        g = Gaussians(*read_gaussians(args.ply))
    else:
        from particlesplat.analysis.particle_arrays import particle_arrays
        from particlesplat.editing.edited_scene import open_edited_scene

        scene = open_edited_scene(args.checkpoint, args.scene, args.context)
        with torch.no_grad():
            g = scene.model.decode(scene.particles).detach().to("cpu")
        arrays, source = particle_arrays(scene.model, scene.particles, g), str(scene.encoded.path)
    cmd = shlex.split(args.splat_transform) if args.splat_transform else None
    background = scene_background(None)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="particlesplat-formats-") as tmp:
        folder = Path(tmp)
        g.save_ply(folder / "scene.ply")
        ref = Gaussians.load_ply(folder / "scene.ply")
        camera = default_view(None, ref).camera(args.width, args.height)
        from particlesplat.rendering.api import render

        with torch.no_grad():
            want = render(ref, camera, background=background).rgb.clamp(0, 1)
        for fmt in FORMATS:
            path = folder / f"ours{fmt.suffix}"
            t0 = time.perf_counter()
            fmt.write(ref, path)
            t1 = time.perf_counter()
            back = Gaussians(*read_gaussians(path))
            t2 = time.perf_counter()
            row: dict[str, Any] = {
                "format": fmt.suffix,
                "bytes_per_gaussian": os.path.getsize(path) / max(ref.num, 1),
                "write_ms": 1e3 * (t1 - t0),
                "read_ms": 1e3 * (t2 - t1),
                "ours_db": _psnr(back, camera, want, background),
            }
            if cmd is not None and fmt.suffix != ".ply":
                out = folder / f"through_{fmt.suffix[1:].replace('.', '_')}.ply"
                err = _convert(cmd, path, out)
                row["through_it_db"] = err or _psnr(Gaussians(*read_gaussians(out)), camera, want, background)
                if fmt.suffix in THEIR_WRITES:
                    theirs = folder / f"theirs{fmt.suffix}"
                    err = _convert(cmd, folder / "scene.ply", theirs, *THEIR_WRITES[fmt.suffix])
                    row["from_it_db"] = err or _psnr(Gaussians(*read_gaussians(theirs)), camera, want, background)
            rows.append(row)
        from particlesplat.analysis.bundle_parts import bundle_parts
        from particlesplat.formats.bundle import write_bundle

        by = "particle" if arrays is None else "object"
        write_bundle(folder / "bundle", by, bundle_parts(ref, by, arrays), {"scene": source})
        merged = Gaussians(*read_gaussians(folder / "bundle" / "manifest.json"))
        bundle_db = _psnr(merged, camera, want, background)
    print(
        f"{machine_line()}; {source or 'the first demo scene'}, {ref.num} Gaussians, "
        f"{args.width}x{args.height} renders against the .ply's"
    )
    head = f"{'format':<16} {'bytes/G':>8} {'write ms':>9} {'read ms':>8} {'ours dB':>8}"
    if cmd is not None:
        head += f" {'through it dB':>14} {'from it dB':>11}"
    print(head)

    def cell(v: Any, width: int) -> str:
        return f"{v:{width}.2f}" if isinstance(v, float) else f"{'-' if v is None else 'error':>{width}}"

    for r in rows:
        line = f"{r['format']:<16} {r['bytes_per_gaussian']:8.2f} {r['write_ms']:9.1f} {r['read_ms']:8.1f} "
        line += cell(min(r["ours_db"], 99.99), 8)
        if cmd is not None:
            line += " " + cell(r.get("through_it_db"), 14) + " " + cell(r.get("from_it_db"), 11)
        print(line)
    for r in rows:
        for key in ("through_it_db", "from_it_db"):
            if isinstance(r.get(key), str):
                print(f"{r['format']} {key}: splat-transform failed: {r[key]}")
    print(f"bundle by {by}, merged: {min(bundle_db, 99.99):.2f} dB")
    if args.json:
        with atomic_write(args.json, "w") as f:
            json.dump({"machine": machine_line(), "scene": source, "rows": rows, "bundle_db": bundle_db}, f, indent=2)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":  # a checkout not installed has no entry point: python -m particlesplat.bench.formats
    raise SystemExit(main())
