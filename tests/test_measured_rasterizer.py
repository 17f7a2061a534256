"""``rasterizer: auto`` on the CPU: chosen by measurement, per kind of render, cached per machine fingerprint."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from particlesplat.core.gaussians import Gaussians
from particlesplat.rendering import measured
from particlesplat.rendering.api import render
from particlesplat.rendering.choice import resolve_rasterizer, use_rasterizer

# fused faster forward, torch faster forward + backward: the Intel Xeon's order
XEON_LIKE = {"fused": {"forward": 40.0, "training": 180.0}, "torch": {"forward": 55.0, "training": 90.0}}


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty cache folder and no memo; restores the run's memo afterwards."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    kept = dict(measured._chosen)
    measured.forget_choices()
    yield tmp_path / "particlesplat" / measured.CACHE_NAME
    measured.forget_choices()
    measured._chosen.update(kept)


def test_choose_takes_the_faster_of_each_kind_and_torch_on_a_tie():
    assert measured.choose(XEON_LIKE) == {"forward": "fused", "training": "torch"}
    tie = {"fused": {"forward": 1.0, "training": 2.0}, "torch": {"forward": 1.0, "training": 2.0}}
    assert measured.choose(tie) == {"forward": "torch", "training": "torch"}


def test_auto_measures_once_caches_and_resolves_by_gradient(fresh_cache, monkeypatch, capsys):
    calls = []
    monkeypatch.setattr(measured, "time_rasterizers", lambda: calls.append(1) or XEON_LIKE)
    cpu = torch.device("cpu")
    with use_rasterizer("auto"):
        assert resolve_rasterizer(None, cpu, grad=False) == "fused"
        assert resolve_rasterizer(None, cpu, grad=True) == "torch"
        assert resolve_rasterizer("fused", cpu, grad=True) == "fused"  # a named one wins
    assert calls == [1]
    line = capsys.readouterr().err.strip()
    assert line.startswith("rasterizer auto: fused for renders, torch for training, measured on ")
    assert str(fresh_cache) in line
    entry = json.loads(fresh_cache.read_text())["entries"][0]
    assert entry["chosen"] == {"forward": "fused", "training": "torch"} and entry["ms"] == XEON_LIKE
    assert entry["fingerprint"] == measured.fingerprint()
    # a new process (the memo forgotten) reads the cache, measures nothing and says nothing
    measured.forget_choices()
    monkeypatch.setattr(measured, "time_rasterizers", lambda: pytest.fail("measured again"))
    assert measured.measured_choice(True) == "torch"
    assert capsys.readouterr().err == ""


def test_another_machine_or_library_version_measures_again(fresh_cache, monkeypatch):
    monkeypatch.setattr(measured, "time_rasterizers", lambda: XEON_LIKE)
    assert measured.measured_choice(True) == "torch"
    amd = {"fused": {"forward": 40.0, "training": 80.0}, "torch": {"forward": 55.0, "training": 100.0}}
    monkeypatch.setattr(measured, "time_rasterizers", lambda: amd)
    monkeypatch.setattr(measured, "fingerprint", lambda: {"cpu": "AMD EPYC", "numba": "0.0"})
    measured.forget_choices()
    assert measured.measured_choice(True) == "fused"
    entries = json.loads(fresh_cache.read_text())["entries"]
    assert [e["chosen"]["training"] for e in entries] == ["torch", "fused"]  # both machines kept


@pytest.mark.parametrize("content", ["{not json", '{"entries": [{"fingerprint": 3, "chosen": "x"}]}', "[]"])
def test_a_broken_cache_is_measured_again_and_rewritten(fresh_cache, monkeypatch, content):
    fresh_cache.parent.mkdir(parents=True)
    fresh_cache.write_text(content)
    monkeypatch.setattr(measured, "time_rasterizers", lambda: XEON_LIKE)
    assert measured.measured_choice(False) == "fused"
    assert json.loads(fresh_cache.read_text())["entries"][-1]["chosen"]["training"] == "torch"


def test_renders_follow_the_choice_of_their_kind(fresh_cache, monkeypatch):
    """A render without gradients takes the forward's choice, one with gradients the training choice: each path
    is seen by the kernel it calls."""
    monkeypatch.setattr(measured, "time_rasterizers", lambda: XEON_LIKE)
    import particlesplat.rendering.api as api

    used = []
    real_fused, real_torch = api.rasterize_fused, api.bin_gaussians
    monkeypatch.setattr(api, "rasterize_fused", lambda *a: used.append("fused") or real_fused(*a))
    monkeypatch.setattr(api, "bin_gaussians", lambda *a: used.append("torch") or real_torch(*a))
    g, cam = measured.timing_scene(200, 32)
    with use_rasterizer("auto"):
        with torch.no_grad():
            render(g, cam)
        means, quats, scales, opacities, sh = (
            t.detach().requires_grad_() for t in (g.means, g.quats, g.scales, g.opacities, g.sh)
        )
        render(Gaussians(means, quats, scales, opacities, sh, g.owner), cam).rgb.sum().backward()
    assert used == ["fused", "torch"]


@pytest.mark.parametrize("mode", ["grad", "no_grad", "inference_mode"])
def test_time_rasterizers_times_both_kinds_of_both(mode):
    """Measured from wherever the first render happens: eval renders under no_grad, encoders under inference_mode."""
    block = {"grad": torch.enable_grad, "no_grad": torch.no_grad, "inference_mode": torch.inference_mode}[mode]
    with block():
        ms = measured.time_rasterizers(n=300, size=32, views=2, repeats=1)
    assert set(ms) == set(measured.CANDIDATES)
    assert all(ms[r][k] > 0 for r in ms for k in ("forward", "training"))


def test_a_command_says_what_it_measured_once(tmp_path):
    """A fresh cache: the first command prints the one line; the second reads the cache and prints nothing of it."""
    code = (
        "import particlesplat.rendering.api; from particlesplat.rendering.measured import measured_choice; "
        "print(measured_choice(False), measured_choice(True))"
    )
    env = {"XDG_CACHE_HOME": str(tmp_path), "PATH": "/usr/bin:/bin"}
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0 and first.stderr.count("rasterizer auto:") == 1
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert second.returncode == 0 and "rasterizer auto" not in second.stderr and second.stdout == first.stdout


def test_a_change_to_the_kernels_measures_again(fresh_cache, monkeypatch):
    """Same machine and package version, other rasterizer code (an install from a newer commit): measured again."""
    monkeypatch.setattr(measured, "time_rasterizers", lambda: XEON_LIKE)
    assert measured.measured_choice(True) == "torch"
    before = measured.fingerprint()
    assert len(before["kernels"]) == 16
    amd = {"fused": {"forward": 40.0, "training": 80.0}, "torch": {"forward": 55.0, "training": 100.0}}
    monkeypatch.setattr(measured, "time_rasterizers", lambda: amd)
    monkeypatch.setattr(measured, "kernels_digest", lambda: "0123456789abcdef")
    measured.forget_choices()
    assert measured.measured_choice(True) == "fused"
    prints = [e["fingerprint"] for e in json.loads(fresh_cache.read_text())["entries"]]
    assert prints == [before, {**before, "kernels": "0123456789abcdef"}]
