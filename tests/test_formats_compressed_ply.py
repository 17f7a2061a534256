"""PlayCanvas's compressed ``.ply`` writer and reader, checked against a reader written from the format's
description (``formats_spec.read_compressed_ply_spec``), on the demo scene and on random Gaussians with SH; the
reader also opens such a file named ``.ply``; bad files are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from formats_spec import (
    C0,
    assert_same_as_ours,
    demo_gaussians,
    original,
    random_gaussians,
    read_compressed_ply_spec,
    render_psnr,
    rotation_dot,
)

from particlesplat.core.errors import UserError
from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.compressed_ply import morton_order, read_compressed_ply, write_compressed_ply
from particlesplat.formats.splat_files import read_gaussians


def _within_chunks(got: np.ndarray, want: np.ndarray, bits: tuple[int, int, int]) -> None:
    """Each value is within half a step of its chunk's range (the range is that of the chunk's originals)."""
    n = len(want)
    for c in range(n // 256 + 1):
        rows = slice(256 * c, min(256 * (c + 1), n))
        if rows.start >= rows.stop:
            break
        span = want[rows].max(0) - want[rows].min(0)
        step = span / (2.0 ** np.array(bits) - 1)
        assert (np.abs(got[rows] - want[rows]) <= step / 2 + 1e-6 * (1 + span)).all(), c


@pytest.mark.parametrize("source, degree", [("demo", 0), ("random", 1), ("random", 3)])
def test_the_spec_reader_reads_what_we_write_within_its_steps(tmp_path, source, degree):
    g = demo_gaussians() if source == "demo" else random_gaussians(700, degree, seed=degree)
    path = tmp_path / "g.compressed.ply"
    write_compressed_ply(g, path)
    spec = read_compressed_ply_spec(path)
    orig = original(g)
    order = morton_order(orig["means"])  # the file's order (the writer's, not part of the format)
    want = {k: v[order] for k, v in orig.items()}
    _within_chunks(spec["means"], want["means"], (11, 10, 11))
    _within_chunks(spec["log_scales"], np.clip(want["log_scales"], -20, 20), (11, 10, 11))
    _within_chunks(C0 * spec["dc"] + 0.5, C0 * want["dc"] + 0.5, (8, 8, 8))
    assert np.abs(spec["opacities"] - want["opacities"]).max() <= 0.5 / 255 + 1e-9
    assert rotation_dot(spec["quats"], want["quats"]).min() > 1 - 2e-5  # 10 bits over ±1/sqrt(2)
    if degree:
        assert np.abs(spec["rest"] - np.clip(want["rest"], -4, 4)).max() <= 8 / 256 + 1e-9
    assert_same_as_ours(Gaussians(*read_compressed_ply(path)), spec)
    assert path.stat().st_size < 16 * g.num + 3 * (degree + 1) ** 2 * g.num + 72 * (g.num // 256 + 1) + 2000


def test_the_demo_scene_renders_as_its_ply_and_opens_under_any_ply_name(tmp_path):
    g = demo_gaussians()
    write_compressed_ply(g, tmp_path / "g.compressed.ply")
    (tmp_path / "renamed.ply").write_bytes((tmp_path / "g.compressed.ply").read_bytes())
    back = Gaussians(*read_gaussians(tmp_path / "renamed.ply"))  # told apart by its header, not its name
    assert render_psnr(back, g) >= 45.0  # 54.4 dB measured


def test_bad_files_are_refused_in_one_line(tmp_path):
    write_compressed_ply(random_gaussians(300, 0, seed=1), tmp_path / "g.compressed.ply")
    data = (tmp_path / "g.compressed.ply").read_bytes()
    head, body = data.split(b"end_header\n")
    cases = {
        "short.compressed.ply": (data[:-7], "element 'vertex' declares 300 rows"),
        "lying.compressed.ply": (
            head.replace(b"element vertex 300", b"element vertex 900") + b"end_header\n" + body,
            "element 'vertex' declares 900 rows",
        ),
        "chunks.compressed.ply": (
            head.replace(b"element chunk 2", b"element chunk 1") + b"end_header\n" + body,
            "element 'chunk' has 1 rows; 300 vertices need 2",
        ),
        "nan.compressed.ply": (
            head + b"end_header\n" + np.float32(np.nan).tobytes() + body[4:],
            "property 'min_x' in element 'chunk' has a non-finite value",
        ),
        "missing.compressed.ply": (
            head.replace(b"packed_scale", b"packed_other") + b"end_header\n" + body,
            "missing property 'packed_scale' in element 'vertex'",
        ),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(UserError) as info:
            read_gaussians(tmp_path / name)
        msg = str(info.value)
        assert msg.startswith(str(tmp_path / name)) and message in msg and "\n" not in msg, msg
