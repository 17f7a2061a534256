"""``particlesplat curve``: plot the validation curves of one to three runs (PSNR and FG-ARI against step) to a
small PNG.

Reads ``RUN/metrics.jsonl`` (the ``val`` records ``particlesplat train`` writes); a torn last line is skipped.
Drawn with pillow only, so the library needs no plotting package.
"""

from __future__ import annotations

import math
from pathlib import Path

from PIL import Image, ImageDraw

from particlesplat.training.runlog import read_log

WIDTH, HEIGHT, MARGIN = 560, 300, 48
PSNR_COLOUR, ARI_COLOUR, AXIS_COLOUR = (31, 119, 180), (214, 39, 40), (60, 60, 60)
# (PSNR, FG-ARI) colours of each run on one plot: the first run's are PSNR_COLOUR and ARI_COLOUR
RUN_COLOURS = ((PSNR_COLOUR, ARI_COLOUR), ((23, 190, 207), (255, 127, 14)), ((44, 160, 44), (148, 103, 189)))
LEGEND_ROW = 14  # pixels a legend row takes below the plot


def read_validation(path: Path) -> list[tuple[int, float, float]]:
    """(step, PSNR dB, FG-ARI) of every validation record in ``path`` (a metrics.jsonl, read line by line and
    checked by :func:`particlesplat.training.runlog.read_log`), in step order; a metric that is null is NaN."""
    records, _ = read_log(path, keep=lambda r: "val" in r)

    def metric(v: object) -> float:
        return float("nan") if v is None else float(v)  # type: ignore[arg-type]

    rows = [(int(r["step"]), metric(r["val"].get("psnr")), metric(r["val"].get("fg_ari"))) for r in records]
    return sorted(rows)


def plot_curve(rows: list[tuple[int, float, float]], title: str = "") -> Image.Image:
    """A WIDTH x HEIGHT RGB plot of one run: PSNR (left axis, dB) and FG-ARI (right axis, 0-1) against step."""
    return plot_curves([("", rows)], title)


def plot_curves(runs: list[tuple[str, list[tuple[int, float, float]]]], title: str = "") -> Image.Image:
    """Up to ``len(RUN_COLOURS)`` runs on one plot, (label, rows) each: PSNR (left axis, dB) and FG-ARI (right
    axis, 0-1) against step, a colour pair per run; WIDTH x (HEIGHT + LEGEND_ROW per run after the first)."""
    if not 1 <= len(runs) <= len(RUN_COLOURS):
        raise ValueError(f"plot_curves draws 1 to {len(RUN_COLOURS)} runs, got {len(runs)}")
    img = Image.new("RGB", (WIDTH, HEIGHT + LEGEND_ROW * (len(runs) - 1)), "white")
    d = ImageDraw.Draw(img)
    x0, x1, y0, y1 = MARGIN, WIDTH - MARGIN, HEIGHT - MARGIN, MARGIN // 2 + 8
    d.rectangle([x0, y1, x1, y0], outline=AXIS_COLOUR)
    if title:
        d.text((x0, 4), title, fill=AXIS_COLOUR)
    rows_all = [r for _, rows in runs for r in rows]
    if not rows_all:
        d.text((x0 + 10, (y0 + y1) // 2), "no validation records yet", fill=AXIS_COLOUR)
        return img
    s_max = max(max(r[0] for r in rows_all), 1)
    psnrs = [r[1] for r in rows_all if math.isfinite(r[1])]  # NaN and inf are not drawn and set no axis
    p_lo, p_hi = min([15.0, *psnrs]), max([30.0, *psnrs])

    def px(step: float) -> float:
        return x0 + (x1 - x0) * step / s_max

    def py(value: float, lo: float, hi: float) -> float:
        return y0 - (y0 - y1) * (value - lo) / (hi - lo)

    for k in range(5):  # gridlines and tick labels
        frac = k / 4
        y = y0 - (y0 - y1) * frac
        d.line([x0, y, x1, y], fill=(225, 225, 225))
        d.text((4, y - 6), f"{p_lo + frac * (p_hi - p_lo):.1f}", fill=PSNR_COLOUR)
        d.text((x1 + 6, y - 6), f"{frac:.2f}", fill=ARI_COLOUR)
        d.text((px(frac * s_max) - 12, y0 + 6), f"{int(frac * s_max)}", fill=AXIS_COLOUR)
    d.text((x1 - 30, y0 + 22), "step", fill=AXIS_COLOUR)
    for i, ((label, rows), (psnr_colour, ari_colour)) in enumerate(zip(runs, RUN_COLOURS, strict=False)):
        steps = [r[0] for r in rows]
        series = (([r[1] for r in rows], p_lo, p_hi, psnr_colour), ([r[2] for r in rows], 0.0, 1.0, ari_colour))
        for values, lo, hi, colour in series:
            pts = [(px(s), py(v, lo, hi)) for s, v in zip(steps, values, strict=True) if math.isfinite(v)]
            if len(pts) > 1:
                d.line(pts, fill=colour, width=2)
            for x, y in pts:
                d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=colour)
        row_y = y0 + 22 + LEGEND_ROW * i
        prefix = f"{label}: " if label else ""
        d.text((x0, row_y), f"{prefix}val PSNR (dB, left)", fill=psnr_colour)
        d.text((x0 + 8 * len(prefix) + 160, row_y), "val FG-ARI (right)", fill=ari_colour)
    return img
