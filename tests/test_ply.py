"""3DGS .ply I/O: round trips, files laid out by hand from the documented layout, errors, atomicity."""

from __future__ import annotations

import math
import struct
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import torch

import particlesplat.formats.ply as ply_module
from particlesplat import Gaussians
from particlesplat.formats.ply import PlyError


def random_gaussians(n: int, degree: int, seed: int = 0) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    return Gaussians(
        torch.randn(n, 3, generator=gen) * 3,
        torch.randn(n, 4, generator=gen),
        torch.exp(torch.randn(n, 3, generator=gen)) * 0.1,
        0.01 + 0.98 * torch.rand(n, generator=gen),
        torch.randn(n, (degree + 1) ** 2, 3, generator=gen),
        torch.randint(-1, 7, (n,), generator=gen),
    )


def layout_names(degree: int, owner: bool) -> list[str]:
    """The documented 3DGS property order."""
    k = (degree + 1) ** 2
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return names + (["owner"] if owner else [])


def write_by_hand(
    path: Path,
    rows: list[dict[str, float]],
    names: list[str],
    *,
    endian: str = "<",
    int_props: tuple[str, ...] = (),
    uchar_props: tuple[str, ...] = (),
    extra_header: str = "",
    truncate: int = 0,
) -> None:
    """A binary .ply written with struct, one row per vertex: floats, except ``int_props`` (int32)
    and ``uchar_props`` (uint8)."""
    fmt = "binary_little_endian" if endian == "<" else "binary_big_endian"
    kind = {n: ("int", "i") for n in int_props} | {n: ("uchar", "B") for n in uchar_props}
    header = f"ply\nformat {fmt} 1.0\ncomment written by hand\nelement vertex {len(rows)}\n"
    header += "".join(f"property {kind.get(n, ('float', 'f'))[0]} {n}\n" for n in names)
    header += extra_header + "end_header\n"
    body = b"".join(
        struct.pack(
            endian + "".join(kind.get(n, ("float", "f"))[1] for n in names),
            *[int(r[n]) if n in kind else r[n] for n in names],
        )
        for r in rows
    )
    data = header.encode("ascii") + body
    path.write_bytes(data[: len(data) - truncate] if truncate else data)


def hand_rows(degree: int) -> tuple[list[dict[str, float]], dict[str, np.ndarray]]:
    """Two vertices with distinct, exactly representable values and the Gaussians they encode."""
    k = (degree + 1) ** 2
    rows, sh = [], np.zeros((2, k, 3))
    opac, scales = [0.25, 0.8], [[0.5, 0.125, 2.0], [1.0, 0.25, 0.0625]]
    for v in range(2):
        r = {"x": 1.5 + v, "y": -2.25, "z": 0.125 * (v + 1), "nx": 0.0, "ny": 0.0, "nz": 0.0}
        for c in range(3):
            r[f"f_dc_{c}"] = sh[v, 0, c] = 0.5 * c - v
        for c in range(3):  # channel-major: f_rest[c * (K - 1) + (k - 1)] is coefficient k of channel c
            for j in range(1, k):
                r[f"f_rest_{c * (k - 1) + j - 1}"] = sh[v, j, c] = 0.25 * j + 0.0625 * c + 0.5 * v
        r["opacity"] = math.log(opac[v] / (1 - opac[v]))
        for i in range(3):
            r[f"scale_{i}"] = math.log(scales[v][i])
        for i, q in enumerate([0.5, -0.5, 0.25, 0.75] if v == 0 else [0.0, 1.0, 0.0, 0.0]):
            r[f"rot_{i}"] = q
        rows.append(r)
    want = {
        "means": np.array([[1.5, -2.25, 0.125], [2.5, -2.25, 0.25]]),
        "sh": sh,
        "opacities": np.array(opac),
        "scales": np.array(scales),
        "quats": np.array([[0.5, -0.5, 0.25, 0.75], [0.0, 1.0, 0.0, 0.0]]),
    }
    return rows, want


def assert_matches(g: Gaussians, want: dict[str, np.ndarray]) -> None:
    for name, value in want.items():
        np.testing.assert_allclose(getattr(g, name).numpy(), value, rtol=1e-6, atol=1e-7, err_msg=name)


# ------------------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_every_degree(tmp_path: Path, degree: int) -> None:
    g = random_gaussians(57, degree, degree)
    path = tmp_path / f"deg{degree}.ply"
    g.save_ply(path)
    back = Gaussians.load_ply(path)
    assert back.sh_degree == degree and len(back) == 57 and back.means.dtype == torch.float32
    for name in ("means", "quats", "sh"):
        assert torch.equal(getattr(back, name), getattr(g, name)), name  # stored as float32: exact
    torch.testing.assert_close(back.scales, g.scales, rtol=2e-6, atol=0)
    torch.testing.assert_close(back.opacities, g.opacities, rtol=0, atol=1e-6)
    assert torch.equal(back.owner, g.owner) and back.owner.dtype == torch.int64
    assert not list(tmp_path.glob(".*tmp"))  # no temporary left behind


def test_round_trip_float64_input_and_empty(tmp_path: Path) -> None:
    g = random_gaussians(5, 1).to(dtype=torch.float64)
    g.save_ply(tmp_path / "a.ply")
    back = Gaussians.load_ply(tmp_path / "a.ply")
    torch.testing.assert_close(back.means.double(), g.means, rtol=1e-7, atol=0)
    e = Gaussians.empty(2)
    e.save_ply(tmp_path / "e.ply")
    back_e = Gaussians.load_ply(tmp_path / "e.ply")
    assert len(back_e) == 0 and back_e.sh_degree == 2


@pytest.mark.parametrize("degree", [0, 3])
def test_written_file_follows_documented_layout(tmp_path: Path, degree: int) -> None:
    """Parse the written file by hand: property order, logit opacity, log scales, channel-major f_rest."""
    g = random_gaussians(6, degree, 4)
    path = tmp_path / "layout.ply"
    g.save_ply(path)
    raw = path.read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    lines = head.decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0" and "element vertex 6" in lines
    props = [ln.split() for ln in lines if ln.startswith("property")]
    assert [p[2] for p in props] == layout_names(degree, owner=True)
    assert all(p[1] == "float" for p in props[:-1]) and props[-1][1] in ("int", "int32")
    names = [p[2] for p in props]
    rec = np.frombuffer(body, dtype=np.dtype([(n, "<f4") for n in names[:-1]] + [("owner", "<i4")]))
    assert len(rec) == 6
    k = (degree + 1) ** 2
    sh = g.sh.numpy()
    for c in range(3):
        np.testing.assert_array_equal(rec[f"f_dc_{c}"], sh[:, 0, c])
        for j in range(1, k):
            np.testing.assert_array_equal(rec[f"f_rest_{c * (k - 1) + j - 1}"], sh[:, j, c])
    o = g.opacities.double().numpy()
    np.testing.assert_allclose(rec["opacity"], np.log(o / (1 - o)), rtol=1e-6, atol=1e-6)
    for i in range(3):
        np.testing.assert_allclose(rec[f"scale_{i}"], np.log(g.scales[:, i].double().numpy()), rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(rec["xyz"[i]], g.means[:, i].numpy())
    for i in range(4):
        np.testing.assert_array_equal(rec[f"rot_{i}"], g.quats[:, i].numpy())
    np.testing.assert_array_equal(rec["owner"], g.owner.numpy())


# ------------------------------------------------------------------------------------------- by hand
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_hand_laid_out_file_without_owner(tmp_path: Path, degree: int) -> None:
    rows, want = hand_rows(degree)
    path = tmp_path / "hand.ply"
    write_by_hand(path, rows, layout_names(degree, owner=False))
    g = Gaussians.load_ply(path)
    assert g.sh_degree == degree
    assert_matches(g, want)
    assert g.owner.tolist() == [-1, -1]


def test_hand_laid_out_big_endian_with_owner_and_extra_element(tmp_path: Path) -> None:
    rows, want = hand_rows(1)
    rows[0]["owner"], rows[1]["owner"] = 3, 0
    path = tmp_path / "hand_be.ply"
    # other tools may add elements after the vertices (declared after it in the header)
    write_by_hand(
        path,
        rows,
        layout_names(1, owner=True),
        endian=">",
        int_props=("owner",),
        extra_header="element extra 0\nproperty float foo\n",
    )
    g = Gaussians.load_ply(path)
    assert_matches(g, want)
    assert g.owner.tolist() == [3, 0]


def test_hand_laid_out_with_extra_uchar_colour_properties(tmp_path: Path) -> None:
    """Other tools add properties (e.g. uchar red/green/blue); they are skipped, offsets stay right."""
    rows, want = hand_rows(1)
    for r in rows:
        r.update(red=255, green=7, blue=0)
    names = layout_names(1, owner=False)
    names = names[:6] + ["red", "green", "blue"] + names[6:]
    path = tmp_path / "extra.ply"
    write_by_hand(path, rows, names, uchar_props=("red", "green", "blue"))
    g = Gaussians.load_ply(path)
    assert_matches(g, want)
    assert g.owner.tolist() == [-1, -1]


def test_hand_laid_out_shuffled_property_order(tmp_path: Path) -> None:
    """Properties are found by name, not position."""
    rows, want = hand_rows(2)
    names = layout_names(2, owner=False)
    names = names[::-1]
    path = tmp_path / "shuffled.ply"
    write_by_hand(path, rows, names)
    assert_matches(Gaussians.load_ply(path), want)


# ------------------------------------------------------------------------------------------- errors
def _expect_error(path: Path, *needles: str) -> None:
    with pytest.raises(PlyError) as info:
        Gaussians.load_ply(path)
    msg = str(info.value)
    assert str(path) in msg or path.name in msg, msg
    for n in needles:
        assert n in msg, msg


@pytest.mark.parametrize(
    "prop, bad",
    [(p, v) for p in ("y", "f_rest_4", "scale_2") for v in (float("nan"), float("inf"), float("-inf"))]
    + [("opacity", float("nan"))],  # an opacity logit of ±inf is an opacity of 1 or 0 (the next test)
)
def test_non_finite_values_are_rejected(tmp_path: Path, bad: float, prop: str) -> None:
    rows, _ = hand_rows(1)
    rows[1][prop] = bad
    path = tmp_path / "bad.ply"
    write_by_hand(path, rows, layout_names(1, owner=False))
    _expect_error(path, prop)


@pytest.mark.parametrize("logit, opacity", [(float("inf"), 1.0), (float("-inf"), 0.0)])
def test_an_infinite_opacity_logit_is_opacity_one_or_zero(tmp_path: Path, logit: float, opacity: float) -> None:
    """Tools that quantise opacity to 8 bits write a stored 0 (or 255) back as a logit of -inf (+inf)."""
    rows, want = hand_rows(1)
    rows[1]["opacity"] = logit
    want["opacities"] = np.array([want["opacities"][0], opacity])
    path = tmp_path / "inf.ply"
    write_by_hand(path, rows, layout_names(1, owner=False))
    assert_matches(Gaussians.load_ply(path), want)


@pytest.mark.parametrize("missing", ["scale_1", "rot_3", "opacity", "f_dc_2", "x"])
def test_missing_property_is_rejected(tmp_path: Path, missing: str) -> None:
    rows, _ = hand_rows(1)
    path = tmp_path / "missing.ply"
    write_by_hand(path, rows, [n for n in layout_names(1, owner=False) if n != missing])
    _expect_error(path, missing)


@pytest.mark.parametrize("count", [6, 3, 12, 48])
def test_f_rest_count_that_is_no_sh_degree(tmp_path: Path, count: int) -> None:
    rows, _ = hand_rows(0)
    for r in rows:
        r.update({f"f_rest_{i}": 0.0 for i in range(count)})
    names = layout_names(0, owner=False)
    names = names[:9] + [f"f_rest_{i}" for i in range(count)] + names[9:]
    path = tmp_path / "rest.ply"
    write_by_hand(path, rows, names)
    _expect_error(path, "f_rest")


@pytest.mark.parametrize("cut", [1, 40, 200])
def test_truncated_file_is_rejected(tmp_path: Path, cut: int) -> None:
    rows, _ = hand_rows(3)
    path = tmp_path / "short.ply"
    write_by_hand(path, rows, layout_names(3, owner=False), truncate=cut)
    _expect_error(path, "truncated")


def test_ascii_ply_is_rejected_with_the_file_name(tmp_path: Path) -> None:
    path = tmp_path / "ascii.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0.0\n")
    _expect_error(path, "ascii")


def test_truncated_header_and_not_a_ply(tmp_path: Path) -> None:
    path = tmp_path / "header.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n")
    _expect_error(path, "header")
    other = tmp_path / "other.ply"
    other.write_bytes(b"\x89PNG\r\n\x1a\n")
    _expect_error(other)
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    _expect_error(empty)


# ------------------------------------------------------------------------------------------- atomicity
def test_failed_write_leaves_existing_file_intact(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "scene.ply"
    old = random_gaussians(10, 1, 1)
    old.save_ply(path)
    before = path.read_bytes()

    real_atomic_write = ply_module.atomic_write

    class Boom(RuntimeError):
        pass

    class FailingFile:
        """Passes the first write (the header) through, then fails mid-write."""

        def __init__(self, f) -> None:
            self.f, self.calls = f, 0

        def write(self, data) -> int:
            self.calls += 1
            if self.calls > 1:
                self.f.write(data[: len(data) // 2])
                raise Boom("disk full")
            return self.f.write(data)

        def __getattr__(self, name):
            return getattr(self.f, name)

    @contextmanager
    def failing_atomic_write(p, mode="wb"):
        with real_atomic_write(p, mode) as f:
            yield FailingFile(f)

    monkeypatch.setattr(ply_module, "atomic_write", failing_atomic_write)
    with pytest.raises(Boom):
        random_gaussians(500, 3, 2).save_ply(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.ply"]
    back = Gaussians.load_ply(path)
    assert torch.equal(back.means, old.means)


@pytest.mark.parametrize(
    "bad_line",
    ["element vertex two", "element vertex -1", "property float", "format", "property float x extra", "vertex 3"],
)
def test_malformed_header_line_is_rejected(tmp_path: Path, bad_line: str) -> None:
    rows, _ = hand_rows(0)
    path = tmp_path / "malformed.ply"
    write_by_hand(path, rows, layout_names(0, owner=False))
    data = path.read_bytes().replace(b"comment written by hand", bad_line.encode("ascii"))
    path.write_bytes(data)
    _expect_error(path)


@pytest.mark.parametrize("field", ["means", "quats", "scales", "opacities", "sh"])
def test_writing_non_finite_values_is_refused(tmp_path: Path, field: str) -> None:
    path = tmp_path / "nan.ply"
    good = random_gaussians(4, 1, 3)
    good.save_ply(path)
    before = path.read_bytes()
    g = random_gaussians(4, 1, 3)
    getattr(g, field).view(4, -1)[2, 0] = float("nan")
    with pytest.raises(ValueError, match=field) as info:
        g.save_ply(path)
    assert str(path) in str(info.value) and "2" in str(info.value)
    assert path.read_bytes() == before
