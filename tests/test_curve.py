"""particlesplat curve: validation records read from metrics.jsonl and drawn where they belong."""

import json

import pytest

from particlesplat.training.curve import ARI_COLOUR, HEIGHT, MARGIN, PSNR_COLOUR, WIDTH, plot_curve, read_validation


def test_reads_val_records_and_skips_a_torn_last_line(tmp_path):
    log = tmp_path / "metrics.jsonl"
    lines = [
        json.dumps({"step": 10, "loss": 1.0}),
        json.dumps({"step": 1000, "val": {"psnr": 25.0, "fg_ari": 0.5}}),
        json.dumps({"step": 500, "val": {"psnr": 20.0, "fg_ari": 0.25}}),
        '{"step": 1010, "lo',
    ]
    log.write_text("\n".join(lines))
    assert read_validation(log) == [(500, 20.0, 0.25), (1000, 25.0, 0.5)]
    log.write_text("\n".join([lines[3], lines[1]]))  # torn in the middle: not a crash, an error naming the line
    with pytest.raises(ValueError, match="line 1"):
        read_validation(log)


def test_points_are_drawn_at_their_step_and_value():
    img = plot_curve([(0, 15.0, 0.0), (1000, 30.0, 1.0)])
    assert img.size == (WIDTH, HEIGHT)
    x0, x1, y0, y1 = MARGIN, WIDTH - MARGIN, HEIGHT - MARGIN, MARGIN // 2 + 8
    # PSNR axis spans 15..30 dB, FG-ARI 0..1: the last point of each lies at the top right corner
    assert img.getpixel((x1, y1)) in (PSNR_COLOUR, ARI_COLOUR)
    assert img.getpixel((x0 + 1, y0 - 1)) in (PSNR_COLOUR, ARI_COLOUR)
    assert img.getpixel(((x0 + x1) // 2, (y0 + y1) // 2 + 40)) == (255, 255, 255)  # nothing off the line
