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


def test_two_runs_share_the_axes_each_in_its_own_colours(tmp_path, capsys):
    from particlesplat.cli.main import main
    from particlesplat.training.curve import LEGEND_ROW, RUN_COLOURS

    for name, psnr, ari in (("a", 20.0, 0.3), ("b", 25.0, 0.6)):
        (tmp_path / name).mkdir()
        records = [{"step": s, "val": {"psnr": psnr + s / 1000, "fg_ari": ari}} for s in (500, 1000)]
        (tmp_path / name / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in records))
    out = tmp_path / "both.png"
    assert main(["curve", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out)]) == 0
    assert "b: 2 validation point(s); last: step 1000, PSNR 26.00 dB" in capsys.readouterr().out
    from PIL import Image

    img = Image.open(out).convert("RGB")
    assert img.size == (WIDTH, HEIGHT + LEGEND_ROW)
    colours = {c for _, c in img.getcolors(1 << 16)}
    for psnr_colour, ari_colour in RUN_COLOURS[:2]:
        assert psnr_colour in colours and ari_colour in colours
    assert not set(RUN_COLOURS[2]) & colours  # a third run's colours only with a third run
    x1, y0, y1 = WIDTH - MARGIN, HEIGHT - MARGIN, MARGIN // 2 + 8
    # one PSNR axis for both (15..30 dB): run b's last point (step 1000, 26 dB) at the right edge, 11/15 up
    assert img.getpixel((x1, round(y0 - (y0 - y1) * 11 / 15))) == RUN_COLOURS[1][0]
    with pytest.raises(ValueError, match="at most 3 runs"):
        main(["curve", *[str(tmp_path / "a")] * 4, "--out", str(out)])


def test_training_loss_is_plotted_below_and_a_run_without_validation_says_so(tmp_path, capsys):
    """A short run (loss logged every 10 steps, no validation yet): the plot has the loss panel, its first and last
    points at the panel's top left and bottom right (log axis), and the command says no validation came yet."""
    from PIL import Image

    from particlesplat.cli.main import main
    from particlesplat.training.curve import LOSS_HEIGHT, RUN_COLOURS, read_training

    run = tmp_path / "short"
    run.mkdir()
    records = [{"step": s, "loss": 1000.0 / s, "psnr": 15.0} for s in (10, 20, 40, 80)]
    (run / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in records))
    assert read_training(run / "metrics.jsonl") == [(10, 100.0), (20, 50.0), (40, 25.0), (80, 12.5)]
    out = tmp_path / "c.png"
    assert main(["curve", str(run), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "no validation yet" in said and "training loss to step 80: 4 records of the running mean" in said
    img = Image.open(out).convert("RGB")
    assert img.size == (WIDTH, HEIGHT + LOSS_HEIGHT)
    x0, x1, y0, y1 = MARGIN, WIDTH - MARGIN, HEIGHT + LOSS_HEIGHT - MARGIN, HEIGHT + 8
    colour = RUN_COLOURS[0][0]
    # log axis from 12.5 (bottom) to 100 (top), steps 0..80 across: (10, 100) and (80, 12.5)

    def drawn(x: float, y: float) -> bool:  # within a pixel (the line's rounding)
        return any(img.getpixel((round(x), round(y) + d)) == colour for d in (-1, 0, 1))

    assert drawn(x0 + (x1 - x0) * 10 / 80, y1) and drawn(x1, y0)
    # (40, 25): log10(25) is 1/3 of the way from log10(12.5) to log10(100)
    assert drawn(x0 + (x1 - x0) * 40 / 80, y0 - (y0 - y1) / 3)
    assert not drawn(x0 + (x1 - x0) * 40 / 80, y0 - (y0 - y1) / 2)


def test_a_long_log_keeps_evenly_spaced_loss_rows_and_the_last(tmp_path):
    """A line a step over 10,000 steps: at most 2 x MAX_LOSS_POINTS rows, every k-th step for one k, the last
    step kept, every logged step counted; validation rows all kept."""
    import json

    from particlesplat.training.curve import MAX_LOSS_POINTS, read_curves

    path = tmp_path / "metrics.jsonl"
    lines = [json.dumps({"step": i, "loss": float(i)}) for i in range(10_000)]
    lines.insert(5_000, json.dumps({"step": 4_999, "val": {"psnr": 20.0, "fg_ari": None}}))
    path.write_text("\n".join(lines) + "\n")
    rows, losses, logged = read_curves(path)
    assert logged == 10_000 and len(rows) == 1 and rows[0][2] != rows[0][2]  # null FG-ARI: NaN
    assert MAX_LOSS_POINTS <= len(losses) <= 2 * MAX_LOSS_POINTS
    steps = [s for s, _ in losses]
    assert steps[0] == 0 and steps[-1] == 9_999 and all(v == float(s) for s, v in losses)
    gaps = {b - a for a, b in zip(steps[:-2], steps[1:-1], strict=True)}
    assert len(gaps) == 1  # evenly thinned (the last row is added whatever its gap)


def test_a_ten_step_run_is_told_as_what_its_log_holds(tmp_path_factory, tmp_path, capsys):
    """A 10-step run at the recipe's log_every (10) logs one training record, the running mean at step 10: the
    command says so, not that one step was logged."""
    from model_data import tiny_config, tiny_dataset

    from particlesplat.cli.main import main

    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=10, log_every=10, val_every=10, ckpt_every=10)
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(tmp_path / "run")]) == 0
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if "loss" in r] == [10]  # what the log holds
    capsys.readouterr()
    assert main(["curve", str(tmp_path / "run"), "--out", str(tmp_path / "c.png")]) == 0
    said = capsys.readouterr().out
    assert "training loss to step 10: 1 record, the running mean logged every 10 steps" in said, said
