"""``particlesplat curve``: plot the validation curves of one to three runs (PSNR and FG-ARI against step) and,
below them, their training loss, to a small PNG.

Reads ``RUN/metrics.jsonl`` (the ``val`` records and the logged training steps ``particlesplat train`` writes); a
torn last line is skipped. Drawn with pillow only, so the library needs no plotting package.
"""

from __future__ import annotations

import math
from pathlib import Path

from PIL import Image, ImageDraw

from particlesplat.training.runlog import LogReader, check_record

WIDTH, HEIGHT, MARGIN = 560, 300, 48
LOSS_HEIGHT = 200  # pixels of the training-loss panel below the validation plot
PSNR_COLOUR, ARI_COLOUR, AXIS_COLOUR = (31, 119, 180), (214, 39, 40), (60, 60, 60)
# (PSNR, FG-ARI) colours of each run on one plot: the first run's are PSNR_COLOUR and ARI_COLOUR
RUN_COLOURS = ((PSNR_COLOUR, ARI_COLOUR), ((23, 190, 207), (255, 127, 14)), ((44, 160, 44), (148, 103, 189)))
LEGEND_ROW = 14  # pixels a legend row takes below the plot
MAX_LOSS_POINTS = 2048  # loss rows kept for the plot (it is WIDTH pixels across): a long log is thinned


def read_validation(path: Path) -> list[tuple[int, float, float]]:
    """(step, PSNR dB, FG-ARI) of every validation record in ``path`` (a metrics.jsonl), in step order; a metric
    that is null is NaN."""
    return read_curves(path)[0]


def read_training(path: Path) -> list[tuple[int, float]]:
    """(step, training loss: the running mean the trainer logs) of the logged steps in ``path``, in step order
    (at most :data:`MAX_LOSS_POINTS` of them, evenly thinned, the last always kept)."""
    return read_curves(path)[1]


def read_curves(path: Path) -> tuple[list[tuple[int, float, float]], list[tuple[int, float]], int]:
    """The validation rows (:func:`read_validation`), the training-loss rows (:func:`read_training`) and the number
    of logged training steps of ``path``, in one streaming reading: each record checked as
    :func:`particlesplat.training.runlog.read_log` checks it (LogError naming the line for a bad line but the
    last, a torn write, which is left out). A long run's log (a line a step) keeps only every k-th loss row
    (k doubling as needed), so its memory stays small whatever the log's size."""

    def metric(v: object) -> float:
        return float("nan") if v is None else float(v)  # type: ignore[arg-type]

    rows: list[tuple[int, float, float]] = []
    losses: list[tuple[int, float]] = []
    count, stride, last = 0, 1, None
    reader = LogReader(path)
    for number, r in reader:
        check_record(r, reader.path, number)
        if isinstance(r.get("val"), dict):
            rows.append((int(r["step"]), metric(r["val"].get("psnr")), metric(r["val"].get("fg_ari"))))
        elif "step" in r and isinstance(r.get("loss"), (int, float)) and not isinstance(r["loss"], bool):
            last = (int(r["step"]), float(r["loss"]))
            if count % stride == 0:
                losses.append(last)
                if len(losses) >= 2 * MAX_LOSS_POINTS:
                    losses, stride = losses[::2], stride * 2
            count += 1
    if last is not None and (not losses or losses[-1] != last):
        losses.append(last)
    return sorted(rows), sorted(losses), count


def plot_curve(rows: list[tuple[int, float, float]], title: str = "") -> Image.Image:
    """A WIDTH x HEIGHT RGB plot of one run: PSNR (left axis, dB) and FG-ARI (right axis, 0-1) against step."""
    return plot_curves([("", rows)], title)


def plot_curves(
    runs: list[tuple[str, list[tuple[int, float, float]]]],
    title: str = "",
    training: list[list[tuple[int, float]]] | None = None,
) -> Image.Image:
    """Up to ``len(RUN_COLOURS)`` runs on one plot, (label, rows) each: PSNR (left axis, dB) and FG-ARI (right
    axis, 0-1) against step, a colour pair per run; WIDTH x (HEIGHT + LEGEND_ROW per run after the first).
    ``training``: each run's (step, loss) rows; when any has rows, a panel of LOSS_HEIGHT pixels below plots them
    (:func:`plot_losses`) on the same step axis."""
    if not 1 <= len(runs) <= len(RUN_COLOURS):
        raise ValueError(f"plot_curves draws 1 to {len(RUN_COLOURS)} runs, got {len(runs)}")
    losses = [r for rows in training or [] for r in rows]
    if losses:
        s_max = max([r[0] for _, rows in runs for r in rows] + [r[0] for r in losses] + [1])
        top = _plot_val(runs, title, s_max)
        bottom = plot_losses(training or [], s_max, [label for label, _ in runs])
        img = Image.new("RGB", (WIDTH, top.height + bottom.height), "white")
        img.paste(top, (0, 0))
        img.paste(bottom, (0, top.height))
        return img
    return _plot_val(runs, title, None)


def _plot_val(runs: list[tuple[str, list[tuple[int, float, float]]]], title: str, step_max: int | None) -> Image.Image:
    """The validation plot of :func:`plot_curves`; ``step_max``: the step at the right edge (None: the last
    validation's)."""
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
    s_max = step_max or max(max(r[0] for r in rows_all), 1)
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


def plot_losses(training: list[list[tuple[int, float]]], step_max: int, labels: list[str]) -> Image.Image:
    """WIDTH x LOSS_HEIGHT: each run's training loss against step (0 .. ``step_max`` across), in its PSNR colour;
    a log axis when every loss is positive, else a linear one."""
    img = Image.new("RGB", (WIDTH, LOSS_HEIGHT), "white")
    d = ImageDraw.Draw(img)
    x0, x1, y0, y1 = MARGIN, WIDTH - MARGIN, LOSS_HEIGHT - MARGIN, 8
    d.rectangle([x0, y1, x1, y0], outline=AXIS_COLOUR)
    values = [v for rows in training for _, v in rows if math.isfinite(v)]
    if not values:
        return img
    log = min(values) > 0
    f = (lambda v: math.log10(v)) if log else (lambda v: v)  # noqa: E731
    lo, hi = f(min(values)), f(max(values))
    hi = hi if hi > lo else lo + 1.0
    for k in range(3):  # gridlines and tick labels
        frac = k / 2
        y = y0 - (y0 - y1) * frac
        d.line([x0, y, x1, y], fill=(225, 225, 225))
        value = lo + frac * (hi - lo)
        d.text((4, y - 6), f"{10**value:.3g}" if log else f"{value:.3g}", fill=AXIS_COLOUR)
        d.text((x0 + (x1 - x0) * frac - 12, y0 + 6), f"{int(frac * step_max)}", fill=AXIS_COLOUR)
    for rows, (colour, _) in zip(training, RUN_COLOURS, strict=False):
        pts = [
            (x0 + (x1 - x0) * s / step_max, y0 - (y0 - y1) * (f(v) - lo) / (hi - lo))
            for s, v in rows
            if math.isfinite(v) and (v > 0 or not log)
        ]
        if len(pts) > 1:
            d.line(pts, fill=colour, width=1)
        elif pts:
            x, y = pts[0]
            d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=colour)
    names = ", ".join(label for label in labels if label)
    d.text(
        (x0, y0 + 22),
        f"training loss ({'log scale' if log else 'linear'}){': ' + names if names else ''}",
        fill=AXIS_COLOUR,
    )
    return img
