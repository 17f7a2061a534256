"""Interoperability with PlayCanvas's splat-transform (npm ``@playcanvas/splat-transform``), where it is installed:
it reads every file we write and we read every file it writes, within the dB targets of a 320x240 render against
the render of our own ``.ply``; on SH data our readers decode its files exactly as it does.

Skipped unless the tool is found: ``$SPLAT_TRANSFORM`` (a command line), ``splat-transform`` on PATH, or an
installed copy that ``npx --no-install`` runs (a test never downloads it). It is never a run-time dependency.
"""

from __future__ import annotations

import functools
import os
import shlex
import shutil
import subprocess

import numpy as np
import pytest
from formats_spec import demo_gaussians, random_gaussians, render_psnr

from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.splat_files import read_gaussians, write_gaussians

pytestmark = pytest.mark.slow

# dB of a 320x240 render against the render of our own .ply
THROUGH_IT = {".spz": 35.0, ".compressed.ply": 35.0, ".splat": 30.0, ".sog": 30.0}  # ours -> it -> .ply
FROM_IT = {".spz": 35.0, ".compressed.ply": 35.0, ".sog": 30.0}  # .ply -> it -> ours


@functools.lru_cache(maxsize=1)
def _command() -> tuple[str, ...] | None:
    if os.environ.get("SPLAT_TRANSFORM"):
        return tuple(shlex.split(os.environ["SPLAT_TRANSFORM"]))
    if shutil.which("splat-transform"):
        return (str(shutil.which("splat-transform")),)
    npx = shutil.which("npx")
    if npx is None:
        return None
    cmd = (npx, "--no-install", "@playcanvas/splat-transform")
    try:
        ok = subprocess.run([*cmd, "--version"], capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    return cmd if ok else None


def _convert(src, dst, *options: str) -> None:
    cmd = _command()
    if cmd is None:
        pytest.skip("splat-transform is not installed (npm install -g @playcanvas/splat-transform)")
    run = subprocess.run(
        [*cmd, "-q", "-w", "-g", "cpu", *options, str(src), str(dst)], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0 and dst.is_file(), f"{cmd[-1]} {src.name} {dst.name}: {run.stderr[-2000:]}"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    folder = tmp_path_factory.mktemp("st")
    g = demo_gaussians()
    g.save_ply(folder / "demo.ply")
    return folder, Gaussians.load_ply(folder / "demo.ply")


@pytest.mark.parametrize("suffix", list(THROUGH_IT))
def test_it_reads_what_we_write(demo, suffix):
    folder, ref = demo
    ours = folder / f"ours{suffix}"
    write_gaussians(ref, ours)
    back = folder / f"ours{suffix.replace('.', '_')}.ply"
    _convert(ours, back)
    db = render_psnr(Gaussians(*read_gaussians(back)), ref)
    print(f"{suffix} written here, converted by splat-transform to .ply: {db:.2f} dB")
    assert db >= THROUGH_IT[suffix]


@pytest.mark.parametrize("suffix", list(FROM_IT))
def test_we_read_what_it_writes(demo, suffix):
    folder, ref = demo
    theirs = folder / f"theirs{suffix}"
    _convert(folder / "demo.ply", theirs, *(["--spz-version", "3"] if suffix == ".spz" else []))
    db = render_psnr(Gaussians(*read_gaussians(theirs)), ref)
    print(f"{suffix} written by splat-transform, read here: {db:.2f} dB")
    assert db >= FROM_IT[suffix]


@pytest.mark.parametrize("suffix", list(FROM_IT))
def test_it_decodes_our_sh_files_as_we_do(tmp_path, suffix):
    """SH degree 2: what it reads of our file (converted to .ply) equals what we read of it."""
    ours = tmp_path / f"sh{suffix}"
    write_gaussians(random_gaussians(2000, 2, seed=8), ours)
    _convert(ours, tmp_path / "back.ply")
    _assert_same(Gaussians(*read_gaussians(ours)), Gaussians.load_ply(tmp_path / "back.ply"))


@pytest.mark.parametrize("suffix", list(FROM_IT))
def test_our_readers_decode_its_sh_files_as_it_does(tmp_path, suffix):
    """SH degree 2 (SOG: its k-means palette, shN): what we read of its file equals what it reads of it."""
    random_gaussians(2000, 2, seed=7).save_ply(tmp_path / "sh.ply")
    _convert(tmp_path / "sh.ply", tmp_path / f"sh{suffix}", *(["--spz-version", "3"] if suffix == ".spz" else []))
    _convert(tmp_path / f"sh{suffix}", tmp_path / "back.ply")
    _assert_same(Gaussians(*read_gaussians(tmp_path / f"sh{suffix}")), Gaussians.load_ply(tmp_path / "back.ply"))


def _assert_same(ours: Gaussians, its: Gaussians) -> None:
    assert ours.sh.shape == its.sh.shape == (2000, 9, 3)
    for name in ("means", "scales", "sh"):
        np.testing.assert_allclose(getattr(ours, name).numpy(), getattr(its, name).numpy(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours.opacities.numpy(), its.opacities.numpy(), atol=2e-6)  # its logit clamp
    q = lambda g: (g.quats / g.quats.norm(dim=1, keepdim=True)).numpy()  # noqa: E731
    assert np.abs((q(ours) * q(its)).sum(1)).min() > 1 - 1e-6


def test_its_default_spz_version_4_reads_as_it_decodes_it(tmp_path):
    """Its default ``.spz`` (version 4: ZSTD streams) reads here as it decodes it (SH degree 2)."""
    random_gaussians(2000, 2, seed=9).save_ply(tmp_path / "sh.ply")
    _convert(tmp_path / "sh.ply", tmp_path / "sh.spz")
    assert (tmp_path / "sh.spz").read_bytes()[:8] == b"NGSP\x04\x00\x00\x00"
    _convert(tmp_path / "sh.spz", tmp_path / "back.ply")
    _assert_same(Gaussians(*read_gaussians(tmp_path / "sh.spz")), Gaussians.load_ply(tmp_path / "back.ply"))
