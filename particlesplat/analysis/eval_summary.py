"""What ``particlesplat eval`` prints of :func:`particlesplat.analysis.evaluate.evaluate_dataset`'s result: the
summary of one split folder, its detail lines (error by region, object localisation, pruning), and the table of a
dataset folder's splits, one row a split."""

from __future__ import annotations

import math

from particlesplat.analysis.metrics import FAR_HEIGHTS, OBJECT_HELD, OVERLAYS, PARTICLES_DRAW, REGIONS
from particlesplat.core.choices import OBJECT_CENTRES


def summary_line(out: dict, context: int, fit: bool) -> str:
    """The mean metrics of one evaluated folder in one line (``fit``: with the latent fit's time)."""
    m = out["mean"]
    return (
        f"{len(out['scenes'])} scenes, {context} context view(s), protocol {out.get('protocol', 'sampled')}: "
        f"PSNR {m['psnr']:.2f} dB ({_db(m['psnr_seen'])} on the pixels a context view sees, "
        f"{_db(m['psnr_unseen'])} on those none does), SSIM {m['ssim']:.3f}, "
        f"depth AbsRel {m['depth_abs_rel']:.3f}, FG-ARI {m['fg_ari']:.3f}, mIoU {m['miou']:.3f} (objects; per "
        f"particle {m['fg_ari_particles']:.3f}, {m['miou_particles']:.3f}), active particles "
        f"{m['active_particles']:.1f} in {m['objects']:.1f} objects, object pixels their particles hold "
        f"(weight >= {OBJECT_HELD}) {_share(m['object_held'])}, Gaussians {m['gaussians']:.0f} "
        f"({_share(m['below_support'], '.1%')} of the opaque object ones > 1 cm below z = 0), "
        f"encode {m['encode_ms']:.1f} ms, "
        + (f"fit {m['fit_ms']:.0f} ms, " if fit else "")
        + f"decode {m['decode_ms']:.1f} ms, render {m['render_ms']:.1f} ms/view"
    )


def _db(value: float) -> str:
    """A PSNR, or "no pixels" where the region had none (NaN)."""
    return f"{value:.2f} dB" if math.isfinite(value) else "no pixels"


def _share(value: float, fmt: str = ".0%") -> str:
    """A share in per cent, or "-" where it is undefined (NaN: nothing to count)."""
    return format(value, fmt) if math.isfinite(value) else "-"


def _shares(items) -> str:
    return "; ".join(
        f"{k} {v['pixel_share']:.1%} of pixels, {v['error_share']:.0%} of the error, "
        + (f"{v['psnr']:.1f} dB" if math.isfinite(v["psnr"]) else "no pixels")
        for k, v in items
    )


def detail_lines(out: dict) -> list[str]:
    """The lines below the summary: where the target views' error lies, object localisation, the pruning table
    (each when ``out`` has it)."""
    lines = []
    if "error_regions" in out:
        regions = out["error_regions"]
        lines.append(
            "target-view error by region: "
            + _shares((k.replace("_", " "), v) for k, v in regions.items() if k in REGIONS)
        )
        heights = [(k.removeprefix("floor_far_").replace("_", " "), v) for k, v in regions.items() if k in FAR_HEIGHTS]
        if heights:
            lines.append("  floor far by height over the support surface: " + _shares(heights))
        overlays = [(k.replace("_", " "), v) for k, v in regions.items() if k in OVERLAYS]
        if overlays:
            lines.append(
                f"  the same pixels split otherwise (particles draw: their weight > {PARTICLES_DRAW}; seen: visible "
                "in a context view): " + _shares(overlays)
            )
    if "localisation" in out:
        lines.append(
            "object localisation (true centre to nearest object centre): "
            + "; ".join(
                f"{m} {s['within_0.05']:.0%} / {s['within_0.1']:.0%} / {s['within_0.15']:.0%} within 0.05 / 0.10 / "
                f"0.15 m (median {s['median_m']:.3f} m)"
                for m, s in out["localisation"].items()
            )
            + f", {out['localisation'][OBJECT_CENTRES[0]]['objects']} objects"
        )
    if "pruning" in out:
        lines.append("z_t thr  opacity thr  per particle  PSNR   FG-ARI  Gaussians  render ms")
        for r in out["pruning"]:
            lines.append(
                f"{r['z_t_threshold']:7.2f}  {r['opacity_threshold']:11.2f}  {r['max_per_particle']:12d}  "
                f"{r['psnr']:5.2f}  {r['fg_ari']:6.3f}  {r['gaussians']:9.0f}  {r['render_ms']:9.1f}"
            )
    return lines


# the split table's columns: (header, key of "mean", format)
SPLIT_COLUMNS = (
    ("PSNR dB", "psnr", ".2f"),
    ("seen dB", "psnr_seen", ".2f"),
    ("unseen dB", "psnr_unseen", ".2f"),
    ("held %", "object_held", ".1%"),
    ("SSIM", "ssim", ".3f"),
    ("AbsRel", "depth_abs_rel", ".3f"),
    ("FG-ARI", "fg_ari", ".3f"),
    ("mIoU", "miou", ".3f"),
    ("FG-ARI pp", "fg_ari_particles", ".3f"),
    ("mIoU pp", "miou_particles", ".3f"),
    ("active", "active_particles", ".1f"),
    ("objects", "objects", ".1f"),
    ("Gaussians", "gaussians", ".0f"),
    ("below %", "below_support", ".1%"),
    ("enc ms", "encode_ms", ".1f"),
    ("fit ms", "fit_ms", ".0f"),
    ("dec ms", "decode_ms", ".1f"),
    ("rend ms", "render_ms", ".1f"),
)
LOCALISATION_HEADER = f"{OBJECT_CENTRES[0]} within 5/10/15 cm, median m"


def _cell(value: float | None, fmt: str) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{100 * value:.1f}" if fmt == ".1%" else format(value, fmt)  # "%" columns hold a share in per cent


def _localisation_cell(out: dict) -> str:
    loc = out.get("localisation", {}).get(OBJECT_CENTRES[0])
    if loc is None:
        return "-"
    median = f"{loc['median_m']:.3f}" if math.isfinite(loc["median_m"]) else "-"
    return f"{loc['within_0.05']:.0%} / {loc['within_0.1']:.0%} / {loc['within_0.15']:.0%}, {median}"


def split_table(outs: dict[str, dict], fit: bool) -> list[str]:
    """A header and one row per evaluated split (``outs``: split name -> its result) of the mean metrics
    :func:`summary_line` prints, and the first object centre method's localisation ("-" where a split has none).
    "pp": per particle (the plain argmax, not grouped into objects); "below %": of the opaque object Gaussians, those
    > 1 cm below z = 0; times per scene, render per view; "fit ms" only with ``fit``."""
    columns = [c for c in SPLIT_COLUMNS if fit or c[1] != "fit_ms"]
    table = [["split", "scenes", *(h for h, _, _ in columns), LOCALISATION_HEADER]]
    for split, out in outs.items():
        cells = [_cell(out["mean"][k], fmt) for _, k, fmt in columns]
        table.append([split, str(len(out["scenes"])), *cells, _localisation_cell(out)])
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    return [
        "  ".join(
            cell.ljust(w) if i in (0, len(row) - 1) else cell.rjust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ).rstrip()
        for row in table
    ]
