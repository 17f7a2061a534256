"""SPZ version 4 (a plaintext header, then one ZSTD stream per array), read by ``read_spz``: files written by a
writer written here from Niantic's specification (``formats_spec.write_spz4_spec``) read as the spec reader reads
them, with SH to degree 3 and degree 4 (kept to 3), with extension records; a version 4 file of what our version 3
file holds reads the same Gaussians; bad files, and a stream that inflates far past what the memory limit allows,
are refused in one line before anything large is held."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest
import zstandard
from formats_spec import (
    assert_same_as_ours,
    original,
    random_gaussians,
    read_spz4_spec,
    read_spz_spec,
    rotation_dot,
    write_spz4_spec,
)

from particlesplat.core.errors import InputWarning, UserError
from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.splat_arrays import SplatFileError
from particlesplat.formats.splat_files import read_gaussians
from particlesplat.formats.spz import read_spz, write_spz


def _read(path) -> tuple[Gaussians, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", InputWarning)
        g = Gaussians(*read_spz(path))
    return g, [str(w.message) for w in caught if issubclass(w.category, InputWarning)]


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_a_version_4_file_reads_as_the_spec_reader_reads_it(tmp_path, degree):
    want = original(random_gaussians(300, degree, seed=10 + degree))
    path = tmp_path / "g.spz"
    write_spz4_spec(path, want)
    spec = read_spz4_spec(path)
    # the spec's steps: the file holds what was written
    assert np.abs(spec["means"] - want["means"]).max() <= 0.5 / 4096 + 1e-9
    assert np.abs(spec["opacities"] - want["opacities"]).max() <= 0.5 / 255 + 1e-9
    assert rotation_dot(spec["quats"], want["quats"]).min() > 1 - 1e-5
    if degree:
        assert np.abs(spec["rest"] - want["rest"]).max() <= 0.5 / 128 + 1e-9
    ours, notes = _read(path)
    assert_same_as_ours(ours, spec)
    assert ours.sh.shape == (300, (degree + 1) ** 2, 3) and not notes
    assert (ours.owner == -1).all()
    # the entry point every command reads Gaussian files through takes it by its extension
    np.testing.assert_array_equal(read_gaussians(path).means.numpy(), ours.means.numpy())


def test_degree_4_keeps_degrees_1_to_3_and_says_so(tmp_path):
    g = original(random_gaussians(50, 3, seed=4))
    extra = np.random.default_rng(4).uniform(-0.5, 0.5, (50, 9, 3))  # the 9 degree-4 coefficients a channel
    g4 = {**g, "rest": np.concatenate([g["rest"], extra], axis=1)}
    write_spz4_spec(tmp_path / "d4.spz", g4)
    spec = read_spz4_spec(tmp_path / "d4.spz")
    assert spec["rest"].shape == (50, 24, 3)
    ours, notes = _read(tmp_path / "d4.spz")
    assert_same_as_ours(ours, {**spec, "rest": spec["rest"][:, :15]})
    assert notes == [f"{tmp_path / 'd4.spz'}: sh_degree: 4; its degree-4 coefficients are left out (read to degree 3)"]


def test_extension_records_are_skipped_by_their_length_and_named(tmp_path):
    g = original(random_gaussians(20, 1, seed=5))
    records = ((0xADBE0002, struct.pack("<3f", -0.5, 0.5, 1.0)), (0x12340001, b""))
    write_spz4_spec(tmp_path / "ext.spz", g, extensions=records)
    ours, notes = _read(tmp_path / "ext.spz")
    assert_same_as_ours(ours, read_spz4_spec(tmp_path / "ext.spz"))
    assert notes == [
        f"{tmp_path / 'ext.spz'}: extension records 0xadbe0002, 0x12340001 ignored (the Gaussians are read as stored)"
    ]


def test_version_4_of_our_version_3_file_reads_the_same_gaussians(tmp_path):
    """What our writer stores (version 3), written again as version 4 from the spec reader's values at the same
    fraction bits, reads back to the same Gaussians: both versions decode one encoding."""
    g = random_gaussians(200, 2, seed=6)
    write_spz(g, tmp_path / "v3.spz")
    write_spz4_spec(tmp_path / "v4.spz", read_spz_spec(tmp_path / "v3.spz"))
    a, b = _read(tmp_path / "v3.spz")[0], _read(tmp_path / "v4.spz")[0]
    np.testing.assert_array_equal(a.means.numpy(), b.means.numpy())
    np.testing.assert_allclose(a.scales.numpy(), b.scales.numpy(), rtol=1e-6)
    np.testing.assert_allclose(a.opacities.numpy(), b.opacities.numpy(), atol=1e-7)
    np.testing.assert_allclose(a.sh.numpy(), b.sh.numpy(), atol=1e-6)
    assert rotation_dot(a.quats.double().numpy(), b.quats.double().numpy()).min() > 1 - 1e-5  # one 9-bit step


def _v4(n: int, streams: list[bytes], degree: int = 0, count: int | None = None, toc: int = 32, table=None) -> bytes:
    packed = [zstandard.ZstdCompressor().compress(s) for s in streams]
    count = len(streams) if count is None else count
    head = struct.pack("<IIIBBBBI", 0x5053474E, 4, n, degree, 12, 0, count, toc) + bytes(12)
    rows = table if table is not None else [(len(c), len(u)) for c, u in zip(packed, streams, strict=True)]
    return head + b"".join(struct.pack("<QQ", *row) for row in rows) + b"".join(packed)


def _streams(n: int) -> list[bytes]:
    """A degree-0 file's five arrays for ``n`` points (an identity rotation: w, the largest, index 3)."""
    return [bytes(9 * n), bytes([255] * n), bytes([128] * 3 * n), bytes([80] * 3 * n), struct.pack("<I", 3 << 30) * n]


def test_bad_version_4_files_are_refused_in_one_line(tmp_path):
    good = _streams(2)
    packed = [zstandard.ZstdCompressor().compress(s) for s in good]
    sizes = [(len(c), len(u)) for c, u in zip(packed, good, strict=True)]
    longer = [good[0] + bytes(5), *good[1:]]  # a positions frame that inflates past what its entry says
    cases = {
        "short.spz": (struct.pack("<II", 0x5053474E, 4) + bytes(8), "truncated SPZ version 4 header (16 of 32"),
        "v5.spz": (struct.pack("<II", 0x5053474E, 5) + bytes(24), "version: 5 in a plaintext header is not supp"),
        "degree.spz": (_v4(2, good, degree=5), "sh_degree: 5 is not supported (0..4)"),
        "streams.spz": (_v4(2, good, count=6), "num_streams: 6, but 2 points of SH degree 0 store 5 (positions"),
        "toc.spz": (_v4(2, good, toc=4000), "toc_offset: 4000 leaves no table of contents"),
        "lying.spz": (_v4(3, good), "positions stream: 18 bytes inflated, but 3 points of SH degree 0 need 27"),
        "past.spz": (_v4(2, good, table=[(10**6, 18), *sizes[1:]]), "positions stream: 1000000 compressed bytes run"),
        "tail.spz": (_v4(2, good) + b"x", "the streams end at byte"),
        "longer.spz": (
            _v4(2, longer, table=[(len(zstandard.ZstdCompressor().compress(longer[0])), 18), *sizes[1:]]),
            "positions stream: inflates to more than 18 bytes, its table of contents says 18",
        ),
        "corrupt.spz": (
            _v4(2, good)[: 32 + 80] + b"\xff" * sizes[0][0] + _v4(2, good)[32 + 80 + sizes[0][0] :],
            "positions stream: corrupt ZSTD data",
        ),
        "huge.spz": (_v4(1 << 30, []), "num_points: 1073741824 is beyond"),
    }
    for name, (data, message) in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(SplatFileError) as info:
            read_spz(tmp_path / name)
        msg = str(info.value)
        assert msg.startswith(f"{tmp_path / name}: ") and message in msg and "\n" not in msg, (name, msg)
    (tmp_path / "ok.spz").write_bytes(_v4(2, good))  # the same bytes, told the truth, read
    g, _ = _read(tmp_path / "ok.spz")
    assert g.num == 2 and np.allclose(g.opacities.numpy(), 1.0) and np.allclose(g.quats.numpy(), [1, 0, 0, 0])


def test_a_zstd_bomb_is_refused_by_the_memory_budget_before_it_inflates(tmp_path, monkeypatch):
    """Two million points of zeros compress to a few KB; the header's count is priced against the limit (what the
    arrays and their decoding would hold, hundreds of MB) before a stream is inflated."""
    n = 2_000_000
    data = _v4(n, _streams(n))
    assert len(data) < 100_000
    (tmp_path / "bomb.spz").write_bytes(data)
    monkeypatch.setenv("PARTICLESPLAT_MEMORY_LIMIT", "64M")
    with pytest.raises(UserError, match=r"bomb\.spz: num_points 2000000"):
        read_spz(tmp_path / "bomb.spz")
