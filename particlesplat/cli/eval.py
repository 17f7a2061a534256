"""``particlesplat eval``: metrics of a model on a folder of scenes (the work: :mod:`particlesplat.analysis`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from particlesplat.core.atomic import check_writable
from particlesplat.core.choices import DEFAULT_FIT, FITTED, OBJECT_CENTRES
from particlesplat.core.device import DEVICE_HELP
from particlesplat.core.errors import OptionError
from particlesplat.data.families import checkpoint_help
from particlesplat.data.folders import check_file, check_split_folder
from particlesplat.rendering.choice import add_rasterizer_option, apply_rasterizer_option

MAX_FIT_LR = 10.0  # --fit-lr: Adam's step on the latents; past this the fit diverges at once


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--checkpoint",
        default=None,
        help=checkpoint_help(),
    )
    parser.add_argument("--data", required=True, help="folder of scene folders (e.g. data/tabletop/test)")
    parser.add_argument("--context", type=int, choices=(1, 2), default=2, help="number of context views")
    parser.add_argument("--no-depth", action="store_true", help="encode the context views without depth")
    parser.add_argument("--json", default=None, help="write per-scene and mean metrics to this JSON file")
    parser.add_argument("--figures", default=None, help="write PNG grids of a few scenes to this folder")
    parser.add_argument("--num-figures", type=int, default=4, help="how many scenes get a figure")
    parser.add_argument("--limit", type=int, default=None, help="evaluate only the first N scenes")
    parser.add_argument(
        "--prune",
        action="store_true",
        help="also report PSNR, FG-ARI, Gaussian count and render time at several z_t/opacity thresholds and with "
        "each particle's most opaque 1/2, 1/4, 1/8, 1/16 of its Gaussians",
    )
    parser.add_argument(
        "--fit-steps",
        type=int,
        default=0,
        help="after encoding, fit the particle latents to the context views for N Adam steps "
        "(a quality mode: seconds a scene; 0 = off)",
    )
    parser.add_argument("--fit-lr", type=float, default=0.02, help="learning rate of --fit-steps")
    parser.add_argument(
        "--fit-latents",
        default=",".join(DEFAULT_FIT),
        help=f"comma-separated latents --fit-steps moves, of {','.join(FITTED)} (default: "
        f"{','.join(DEFAULT_FIT)}, which keeps the particles in place)",
    )
    parser.add_argument(
        "--z-t-threshold",
        type=float,
        default=None,
        help="draw the particles with z_t at or above this (default: the model's background.mask_threshold, "
        "as the viewer and particlesplat render draw them; 0 = every particle)",
    )
    parser.add_argument("--device", default=None, help=DEVICE_HELP)
    add_rasterizer_option(parser)


def run(args: argparse.Namespace) -> int:
    latents = tuple(k.strip() for k in args.fit_latents.split(","))
    if args.fit_steps < 0 or not args.fit_lr > 0 or not set(latents) <= set(FITTED):
        raise OptionError(
            f"--fit-steps must be >= 0, --fit-lr > 0 and --fit-latents some of {','.join(FITTED)}; got "
            f"{args.fit_steps}, {args.fit_lr:g}, {','.join(latents)[:80]}"
        )
    from particlesplat.core.outputs import guard_outputs

    guard_outputs(
        [("--json", args.json), ("--figures", args.figures)],
        [("--checkpoint", args.checkpoint), ("--data", args.data)],
    )
    from particlesplat.core.limits import check_option_range

    check_option_range(args.fit_lr, "--fit-lr", 0.0, MAX_FIT_LR, low_open=True)
    check_option_range(args.z_t_threshold, "--z-t-threshold", 0.0, 1.0)  # z_t is a probability
    if args.json:
        check_writable(args.json)  # before the work, not after it
    if args.figures and args.num_figures > 0:
        check_writable(Path(args.figures) / "figure.png")
    check_split_folder(args.data, "--data")  # before torch loads: a typo is one quick line
    check_file(args.checkpoint, "--checkpoint")
    apply_rasterizer_option(args)
    from particlesplat.analysis.evaluate import evaluate_dataset, json_safe
    from particlesplat.analysis.metrics import FAR_HEIGHTS, OVERLAYS, PARTICLES_DRAW, REGIONS
    from particlesplat.core.atomic import atomic_write
    from particlesplat.core.device import resolve_device
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.model import load_model, read_checkpoint
    from particlesplat.model.provenance import describe

    device = resolve_device(args.device)
    path = args.checkpoint or default_checkpoint(args.data)  # the shipped model of the data's family
    model = load_model(path, device=device)
    ckpt = read_checkpoint(path)
    print(f"{path}: step {ckpt['step']}; {describe(ckpt.get('provenance'))}")
    out = evaluate_dataset(
        model,
        args.data,
        context=args.context,
        limit=args.limit,
        figures=Path(args.figures) if args.figures else None,
        num_figures=args.num_figures,
        prune=args.prune,
        use_depth=not args.no_depth,
        fit_steps=args.fit_steps,
        fit_lr=args.fit_lr,
        fit_latents=latents,
        z_t_threshold=args.z_t_threshold,
    )
    m = out["mean"]
    print(
        f"{len(out['scenes'])} scenes, {args.context} context view(s): PSNR {m['psnr']:.2f} dB, SSIM {m['ssim']:.3f}, "
        f"depth AbsRel {m['depth_abs_rel']:.3f}, FG-ARI {m['fg_ari']:.3f}, mIoU {m['miou']:.3f} (objects; per "
        f"particle {m['fg_ari_particles']:.3f}, {m['miou_particles']:.3f}), active particles "
        f"{m['active_particles']:.1f} in {m['objects']:.1f} objects, Gaussians {m['gaussians']:.0f} "
        f"({100 * m['below_support']:.1f} % of the opaque object ones > 1 cm below z = 0), "
        f"encode {m['encode_ms']:.1f} ms, "
        + (f"fit {m['fit_ms']:.0f} ms, " if args.fit_steps else "")
        + f"decode {m['decode_ms']:.1f} ms, render {m['render_ms']:.1f} ms/view"
    )
    if "error_regions" in out:
        print(
            "target-view error by region: "
            + "; ".join(
                f"{k.replace('_', ' ')} {v['pixel_share']:.1%} of pixels, {v['error_share']:.0%} of the error, "
                f"{v['psnr']:.1f} dB"
                for k, v in out["error_regions"].items()
                if k in REGIONS
            )
        )
        heights = {k: v for k, v in out["error_regions"].items() if k in FAR_HEIGHTS}
        if heights:
            print(
                "  floor far by height over the support surface: "
                + "; ".join(
                    f"{k.removeprefix('floor_far_').replace('_', ' ')} {v['pixel_share']:.1%} of pixels, "
                    f"{v['error_share']:.0%} of the error, {v['psnr']:.1f} dB"
                    for k, v in heights.items()
                )
            )
        overlays = {k: v for k, v in out["error_regions"].items() if k in OVERLAYS}
        if overlays:
            print(
                f"  the same pixels split otherwise (particles draw: their weight > {PARTICLES_DRAW}; seen: visible "
                "in a context view): "
                + "; ".join(
                    f"{k.replace('_', ' ')} {v['pixel_share']:.1%} of pixels, {v['error_share']:.0%} of the error, "
                    f"{v['psnr']:.1f} dB"
                    for k, v in overlays.items()
                )
            )
    if "localisation" in out:
        print(
            "object localisation (true centre to nearest object centre): "
            + "; ".join(
                f"{m} {s['within_0.05']:.0%} / {s['within_0.1']:.0%} / {s['within_0.15']:.0%} within 0.05 / 0.10 / "
                f"0.15 m (median {s['median_m']:.3f} m)"
                for m, s in out["localisation"].items()
            )
            + f", {out['localisation'][OBJECT_CENTRES[0]]['objects']} objects"
        )
    if "pruning" in out:
        print("z_t thr  opacity thr  per particle  PSNR   FG-ARI  Gaussians  render ms")
        for r in out["pruning"]:
            print(
                f"{r['z_t_threshold']:7.2f}  {r['opacity_threshold']:11.2f}  {r['max_per_particle']:12d}  "
                f"{r['psnr']:5.2f}  {r['fg_ari']:6.3f}  {r['gaussians']:9.0f}  {r['render_ms']:9.1f}"
            )
    if args.json:
        with atomic_write(args.json, "w") as f:
            json.dump(json_safe(out), f, indent=2, allow_nan=False)
    return 0
