"""``particlesplat bench encode``: checkpoints timed in turns on the scenes ``eval`` uses; the median round per
checkpoint, its ratio to the first."""

from __future__ import annotations

import json

import pytest
from model_data import tiny_dataset
from test_model import tiny_model

from particlesplat.cli.main import main
from particlesplat.core.errors import OptionError
from particlesplat.model import save_checkpoint


def test_bench_encode_times_checkpoints_in_turns(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    plain, refined = tmp_path / "plain.pt", tmp_path / "refined.pt"
    save_checkpoint(plain, tiny_model(1, refine_steps=0), 5)
    save_checkpoint(refined, tiny_model(1, refine_steps=1, refine_hidden=16), 5)
    out = tmp_path / "encode.json"
    args = ["bench", "encode", "--data", str(data / "val"), "--checkpoint", str(plain), str(refined)]
    assert main([*args, "--scenes", "1", "--rounds", "3", "--threads", "1", "--device", "cpu", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "; cpu; 1 scenes of" in text and "3 rounds" in text
    rows = json.loads(out.read_text())["rows"]
    assert [r["checkpoint"] for r in rows] == [str(plain), str(refined)]
    for r in rows:
        assert len(r["rounds_ms"]) == 3 and r["total_ms"] == sorted(r["rounds_ms"])[1]  # the median round
        assert r["total_ms"] == pytest.approx(r["encode_ms"] + r["decode_ms"]) and r["encode_ms"] > 0
    assert rows[0]["ratio"] == 1.0 and rows[1]["ratio"] == pytest.approx(rows[1]["total_ms"] / rows[0]["total_ms"])


def test_bench_encode_refuses_bad_options(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    small, large = tmp_path / "small.pt", tmp_path / "large.pt"
    save_checkpoint(small, tiny_model(1), 5)
    save_checkpoint(large, tiny_model(1, resolution=64), 5)
    base = ["bench", "encode", "--data", str(data / "val")]
    with pytest.raises(OptionError, match="--scenes and --rounds must be >= 1"):
        main([*base, "--checkpoint", str(small), "--rounds", "0"])
    with pytest.raises(OptionError, match=r"one image size, got \[32, 64\]"):
        main([*base, "--checkpoint", str(small), str(large)])
    with pytest.raises(OptionError, match="--device 'gpu0': expected cpu, cuda or cuda:N"):
        main([*base, "--checkpoint", str(small), "--device", "gpu0"])
