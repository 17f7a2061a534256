"""The closed-form symmetric 3x3 eigensolver against LAPACK's (``torch.linalg.eigh``, float64)."""

from __future__ import annotations

import pytest
import torch

from particlesplat.model.eigh3 import eigh3


def _rotations(n: int, gen: torch.Generator) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.randn(n, 3, 3, generator=gen, dtype=torch.float64))
    return q


def _cases() -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    M = torch.randn(2000, 3, 3, generator=gen, dtype=torch.float64)
    R = _rotations(300, gen)
    out = {"random": M @ M.mT, "indefinite": M + M.mT}
    # Gaussian covariances span six decades (scales 1e-4 to 1e-1 m)
    span = torch.tensor([1e-8, 1e-5, 1e-2], dtype=torch.float64) * torch.rand(
        300, 3, generator=gen, dtype=torch.float64
    )
    out["anisotropic"] = R @ torch.diag_embed(span) @ R.mT
    spectra = {
        "two equal, third smaller": [0.04, 0.04, 0.0025],
        "two equal, third larger": [0.0025, 0.0025, 0.04],
        "all equal": [0.3, 0.3, 0.3],
        "zero": [0.0, 0.0, 0.0],
        "nearly equal pair": [1.0, 1.0 + 1e-9, 2.0],
        "rank one": [0.0, 0.0, 5.0],
    }
    for name, values in spectra.items():
        d = torch.diag_embed(torch.tensor(values, dtype=torch.float64).expand(300, 3))
        out[name] = R @ d @ R.mT
        out[name + ", axis-aligned"] = d.clone()
    return {k: 0.5 * (v + v.mT) for k, v in out.items()}


@pytest.mark.parametrize("name", list(_cases()))
def test_matches_lapack_and_reconstructs(name):
    A = _cases()[name]
    lam, U = eigh3(A)
    ref, _ = torch.linalg.eigh(A)
    scale = A.abs().amax(dim=(-2, -1), keepdim=True).clamp_min(1e-300)
    assert float(((lam - ref).abs() / scale[..., 0]).max()) < 1e-13
    assert float(((U @ torch.diag_embed(lam) @ U.mT - A).abs() / scale).max()) < 1e-13
    torch.testing.assert_close(U.mT @ U, torch.eye(3, dtype=torch.float64).expand_as(U), rtol=0, atol=1e-13)
    torch.testing.assert_close(torch.linalg.det(U), torch.ones(A.shape[0], dtype=torch.float64), rtol=0, atol=1e-12)
    assert bool((lam[:, 1:] >= lam[:, :-1] - 1e-14 * scale[:, 0]).all())  # ascending, as eigh


def test_batch_shapes_and_bad_input():
    A = _cases()["random"][:24].reshape(2, 3, 4, 3, 3)
    lam, U = eigh3(A)
    assert lam.shape == (2, 3, 4, 3) and U.shape == (2, 3, 4, 3, 3)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        eigh3(torch.zeros(4, 2, 2, dtype=torch.float64))
