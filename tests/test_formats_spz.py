"""The SPZ v3 writer and reader, checked against a reader written from Niantic's specification
(``formats_spec.read_spz_spec``), on the demo scene and on random Gaussians with SH to degree 3; a version 2 file
laid out by hand reads; bad files are refused in one line."""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest
from formats_spec import (
    assert_same_as_ours,
    demo_gaussians,
    original,
    random_gaussians,
    read_spz_spec,
    render_psnr,
    rotation_dot,
)

from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.splat_arrays import SplatFileError
from particlesplat.formats.spz import read_spz, write_spz


@pytest.mark.parametrize("source, degree", [("demo", 0), ("random", 1), ("random", 3)])
def test_the_spec_reader_reads_what_we_write_within_its_steps(tmp_path, source, degree):
    g = demo_gaussians() if source == "demo" else random_gaussians(400, degree, seed=degree)
    path = tmp_path / "g.spz"
    write_spz(g, path)
    spec, want = read_spz_spec(path), original(g)
    assert np.abs(spec["means"] - want["means"]).max() <= 0.5 / 4096 + 1e-6  # 12 fraction bits
    assert np.abs(spec["opacities"] - want["opacities"]).max() <= 0.5 / 255 + 1e-9
    dc_range = 127.5 / (0.15 * 255)  # the byte's range: |dc| <= 3.33
    assert np.abs(spec["dc"] - np.clip(want["dc"], -dc_range, dc_range)).max() <= 0.5 / (0.15 * 255) + 1e-9
    stored = np.clip(want["log_scales"], -10.0, 255 / 16 - 10.0)  # the byte's range
    assert np.abs(spec["log_scales"] - stored).max() <= 0.5 / 16 + 1e-9
    assert rotation_dot(spec["quats"], want["quats"]).min() > 1 - 1e-5  # 9 bits a component
    if degree:
        step = np.where(np.arange(want["rest"].shape[1]) < 3, 8, 16)[None, :, None] / 128  # 5 bits, then 4
        assert (np.abs(spec["rest"] - want["rest"]) <= step / 2 + 0.5 / 128 + 1e-9).all()
    assert_same_as_ours(Gaussians(*read_spz(path)), spec)


def test_the_demo_scene_renders_as_its_ply(tmp_path):
    g = demo_gaussians()
    write_spz(g, tmp_path / "g.spz")
    assert render_psnr(Gaussians(*read_spz(tmp_path / "g.spz")), g) >= 45.0  # 52.3 dB measured


def test_a_version_2_file_laid_out_by_hand_reads(tmp_path):
    """Version 2 stores the rotation as x, y, z bytes (c * 127.5 + 127.5), w from the unit norm."""
    pos = [round(v * 4096) & 0xFFFFFF for v in (1.5, -0.25, 0.125)]
    payload = struct.pack("<IIIBBBB", 0x5053474E, 2, 1, 0, 12, 0, 0)
    payload += b"".join(struct.pack("<I", p)[:3] for p in pos)
    payload += bytes([204])  # alpha 0.8
    payload += bytes([128, 166, 90])  # colours: dc = (b / 255 - 0.5) / 0.15
    payload += bytes([80, 96, 112])  # log scales -5, -4, -3
    payload += bytes([255, 127, 127])  # x = 1, y = z = -0.002
    (tmp_path / "v2.spz").write_bytes(gzip.compress(payload))
    g = Gaussians(*read_spz(tmp_path / "v2.spz"))
    np.testing.assert_allclose(g.means.numpy(), [[1.5, -0.25, 0.125]], atol=1e-6)
    np.testing.assert_allclose(g.opacities.numpy(), [0.8], atol=1e-6)
    np.testing.assert_allclose(g.sh[0, 0].numpy(), [(b / 255 - 0.5) / 0.15 for b in (128, 166, 90)], atol=1e-5)
    np.testing.assert_allclose(np.log(g.scales.numpy()), [[-5, -4, -3]], atol=1e-5)
    assert abs(float(g.quats[0, 1])) > 0.999


def test_bad_files_are_refused_in_one_line(tmp_path):
    write_spz(random_gaussians(3, 0, seed=1), tmp_path / "g.spz")
    raw = gzip.decompress((tmp_path / "g.spz").read_bytes())
    cases = {
        "lying.spz": gzip.compress(raw[:8] + struct.pack("<I", 4) + raw[12:]),  # 4 points, bytes for 3
        "short.spz": gzip.compress(raw[:-1]),
        "degree.spz": gzip.compress(raw[:12] + bytes([7]) + raw[13:]),
        "magic.spz": gzip.compress(b"XXXX" + raw[4:]),
        "v4.spz": struct.pack("<II", 0x5053474E, 4) + bytes(24),
        "plain.spz": b"hello, not gzip",
        "huge.spz": gzip.compress(raw[:8] + struct.pack("<I", 1 << 30) + raw[12:]),
    }
    messages = {
        "lying.spz": "num_points: 4 points of SH degree 0 need",
        "short.spz": "num_points: 3 points of SH degree 0 need",
        "degree.spz": "sh_degree: 7 is not supported",
        "magic.spz": "magic: 0x58585858 is not SPZ's",
        "v4.spz": "toc_offset: 0 leaves no table of contents",  # version 4: tests/test_formats_spz4.py
        "plain.spz": "not an SPZ file",
        "huge.spz": "num_points: 1073741824 is beyond",
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(SplatFileError) as info:
            read_spz(tmp_path / name)
        msg = str(info.value)
        assert msg.startswith(str(tmp_path / name)) and messages[name] in msg and "\n" not in msg, msg


def test_a_large_scene_takes_fewer_fraction_bits_and_beyond_24_bits_is_refused(tmp_path):
    g = random_gaussians(3, 0, seed=1)
    g.means[1, 2] = 5000.0  # beyond 12 fraction bits' ±2048 m: 10 bits reach ±8192 m
    write_spz(g, tmp_path / "far.spz")
    assert gzip.decompress((tmp_path / "far.spz").read_bytes())[13] == 10
    assert np.abs(read_spz_spec(tmp_path / "far.spz")["means"] - g.means.double().numpy()).max() <= 0.5 / 1024 + 1e-9
    g.means[1, 2] = 1e7  # beyond 2**23 m
    with pytest.raises(ValueError, match=r"huge\.spz: cannot write SPZ: position .* of Gaussian 1 is beyond ±8388607"):
        write_spz(g, tmp_path / "huge.spz")
    assert not (tmp_path / "huge.spz").exists()
