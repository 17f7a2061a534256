"""Edge cases of file I/O: permissions of atomic writes, .ply values beyond float32, truncation messages."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
import torch

from particlesplat import Gaussians
from particlesplat.core.atomic import atomic_path, atomic_write
from particlesplat.formats.ply import PlyError

_LAYOUT = [
    "x",
    "y",
    "z",
    "nx",
    "ny",
    "nz",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
]


def _write_by_hand(path, rec: np.ndarray) -> None:
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(rec)}"]
    header += [f"property float {n}" for n in _LAYOUT] + ["end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + rec.tobytes())


def _records(n: int) -> np.ndarray:
    rec = np.zeros(n, dtype=np.dtype([(name, "<f4") for name in _LAYOUT]))
    rec["rot_0"] = 1.0
    return rec


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_atomic_writes_get_plain_open_permissions(tmp_path, umask: int) -> None:
    old = os.umask(umask)
    try:
        with atomic_write(tmp_path / "a.txt", "w") as f:
            f.write("x")
        with atomic_path(tmp_path / "b.bin") as p:
            p.write_bytes(b"y")
    finally:
        os.umask(old)
    for name in ("a.txt", "b.bin"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o666 & ~umask


def test_scale_beyond_float32_is_rejected_naming_property_and_vertex(tmp_path) -> None:
    rec = _records(4)
    rec["scale_1"][2] = 100.0  # exp(100) overflows float32
    _write_by_hand(tmp_path / "big.ply", rec)
    with pytest.raises(PlyError, match=r"big\.ply.*'scale_1' at vertex 2"):
        Gaussians.load_ply(tmp_path / "big.ply")


def test_extreme_opacity_logits_give_finite_opacities(tmp_path) -> None:
    rec = _records(2)
    rec["opacity"] = [-1000.0, 1000.0]
    _write_by_hand(tmp_path / "o.ply", rec)
    g = Gaussians.load_ply(tmp_path / "o.ply")
    assert torch.equal(g.opacities, torch.tensor([0.0, 1.0]))


def test_truncation_names_the_first_missing_property(tmp_path) -> None:
    rec = _records(3)
    _write_by_hand(tmp_path / "t.ply", rec)
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[: -4 * 5])  # the last vertex loses scale_2 and rot_0..3
    with pytest.raises(PlyError, match=r"t\.ply: truncated.*vertex 2, property 'scale_2'"):
        Gaussians.load_ply(tmp_path / "t.ply")
