"""Gaussians container and SH colours against hand-computed matrices and sphere quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from reference_render import covariance_reference, quat_to_rotmat_reference, sh_basis_reference

from particlesplat import Gaussians
from particlesplat.core.sh import eval_sh_colors, num_sh_bases, rgb_to_sh_dc, sh_basis, sh_degree_from_bases

F64 = torch.float64


def random_gaussians(n: int, degree: int, seed: int = 0, dtype: torch.dtype = torch.float32) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    return Gaussians(
        torch.randn(n, 3, generator=gen, dtype=dtype),
        torch.randn(n, 4, generator=gen, dtype=dtype),
        torch.rand(n, 3, generator=gen, dtype=dtype) + 0.01,
        torch.rand(n, generator=gen, dtype=dtype),
        torch.randn(n, (degree + 1) ** 2, 3, generator=gen, dtype=dtype),
        torch.randint(-1, 3, (n,), generator=gen),
    )


def _rot_z(theta: float) -> torch.Tensor:
    c, s = math.cos(theta), math.sin(theta)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=F64)


def _rot_x(theta: float) -> torch.Tensor:
    c, s = math.cos(theta), math.sin(theta)
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]], dtype=F64)


def test_covariances_hand_computed() -> None:
    a, b = 0.7, -1.2
    # wxyz: rotation by a about z, then by b about x composed as R = Rz(a) Rx(b)
    qz = torch.tensor([math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)], dtype=F64)
    qx = torch.tensor([math.cos(b / 2), math.sin(b / 2), 0.0, 0.0], dtype=F64)
    w1, x1, y1, z1 = qz
    w2, x2, y2, z2 = qx
    q = torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )
    s = torch.tensor([0.3, 0.05, 1.7], dtype=F64)
    quats = torch.stack([qz, qx, q, 3.0 * q, torch.zeros(4, dtype=F64)])  # unnormalised and zero too
    g = Gaussians(
        torch.zeros(5, 3, dtype=F64),
        quats,
        s.repeat(5, 1),
        torch.ones(5, dtype=F64),
        torch.zeros(5, 1, 3, dtype=F64),
        torch.zeros(5, dtype=torch.int64),
    )
    S = torch.diag(s)
    Rs = [_rot_z(a), _rot_x(b), _rot_z(a) @ _rot_x(b), _rot_z(a) @ _rot_x(b), torch.eye(3, dtype=F64)]
    want = torch.stack([R @ S @ S.T @ R.T for R in Rs])
    torch.testing.assert_close(g.covariances(), want, atol=1e-12, rtol=0)
    torch.testing.assert_close(g.rotations(), torch.stack(Rs), atol=1e-12, rtol=0)


def test_covariances_random_vs_reference() -> None:
    g = random_gaussians(50, 0, dtype=F64)
    torch.testing.assert_close(g.covariances(), covariance_reference(g.quats, g.scales), atol=1e-12, rtol=0)
    torch.testing.assert_close(g.rotations(), quat_to_rotmat_reference(g.quats), atol=1e-12, rtol=0)
    cov = g.covariances()
    torch.testing.assert_close(cov, cov.transpose(-1, -2), atol=1e-14, rtol=0)
    assert (torch.linalg.eigvalsh(cov) > -1e-12).all()
    # zero quaternion: identity, with finite (zero) gradients
    q = torch.zeros(1, 4, dtype=F64, requires_grad=True)
    g0 = Gaussians(
        torch.zeros(1, 3, dtype=F64),
        q,
        torch.tensor([[1.0, 2.0, 3.0]], dtype=F64),
        torch.ones(1, dtype=F64),
        torch.zeros(1, 1, 3, dtype=F64),
        torch.zeros(1, dtype=torch.int64),
    )
    torch.testing.assert_close(g0.covariances()[0], torch.diag(torch.tensor([1.0, 4.0, 9.0], dtype=F64)))
    g0.covariances().sum().backward()
    assert torch.isfinite(q.grad).all()


def test_validation_errors() -> None:
    g = random_gaussians(4, 1)
    with pytest.raises(ValueError, match="means"):
        Gaussians(g.means[:, :2], g.quats, g.scales, g.opacities, g.sh, g.owner)
    with pytest.raises(ValueError, match="quats"):
        Gaussians(g.means, g.quats[:3], g.scales, g.opacities, g.sh, g.owner)
    with pytest.raises(ValueError, match="opacities"):
        Gaussians(g.means, g.quats, g.scales, g.opacities[:, None], g.sh, g.owner)
    with pytest.raises(ValueError, match="sh"):
        Gaussians(g.means, g.quats, g.scales, g.opacities, g.sh[:, :, :2], g.owner)
    with pytest.raises(ValueError):
        Gaussians(g.means, g.quats, g.scales, g.opacities, torch.zeros(4, 6, 3), g.owner)  # 6: no degree
    g32 = Gaussians(g.means, g.quats, g.scales, g.opacities, g.sh, g.owner.to(torch.int32))
    assert g32.owner.dtype == torch.int64


def test_cat_pads_sh_and_keeps_order() -> None:
    a, b, c = random_gaussians(3, 0, 1), random_gaussians(4, 2, 2), random_gaussians(2, 1, 3)
    g = Gaussians.cat([a, b, c])
    assert len(g) == 9 and g.sh_degree == 2 and g.sh.shape == (9, 9, 3)
    torch.testing.assert_close(g.means, torch.cat([a.means, b.means, c.means]))
    torch.testing.assert_close(g.sh[:3, :1], a.sh)
    assert (g.sh[:3, 1:] == 0).all() and (g.sh[7:, 4:] == 0).all()
    torch.testing.assert_close(g.sh[3:7], b.sh)
    torch.testing.assert_close(g.sh[7:, :4], c.sh)
    assert torch.equal(g.owner, torch.cat([a.owner, b.owner, c.owner]))
    # padding with zero coefficients leaves the colours unchanged
    center = torch.tensor([0.3, -2.0, 1.0])
    torch.testing.assert_close(g.colors(center)[:3], a.colors(center))
    with pytest.raises(ValueError):
        Gaussians.cat([])


def test_subset_of_owner_to_detach() -> None:
    g = random_gaussians(20, 1, 5)
    mask = g.opacities > 0.5
    sub = g.subset(mask)
    assert len(sub) == int(mask.sum())
    torch.testing.assert_close(sub.scales, g.scales[mask])
    idx = torch.tensor([4, 1, 1, 7])
    sub2 = g.subset(idx)
    torch.testing.assert_close(sub2.sh, g.sh[idx])
    assert torch.equal(sub2.owner, g.owner[idx])
    for owners in (0, [1, 2], -1, torch.tensor([2])):
        o = torch.as_tensor(owners).reshape(-1)
        sel = g.of_owner(owners)
        keep = torch.isin(g.owner, o)
        assert len(sel) == int(keep.sum()) > 0
        assert torch.isin(sel.owner, o).all()
        torch.testing.assert_close(sel.means, g.means[keep])
    assert len(g.of_owner(17)) == 0
    g64 = g.to(dtype=F64)
    assert g64.means.dtype == F64 and g64.sh.dtype == F64 and g64.owner.dtype == torch.int64
    torch.testing.assert_close(g64.quats, g.quats.double())
    assert g.to("cpu").device.type == "cpu"
    leaf = g.means.clone().requires_grad_(True)
    gl = Gaussians(leaf * 2, g.quats, g.scales, g.opacities, g.sh, g.owner)
    assert gl.means.requires_grad and not gl.detach().means.requires_grad
    e = Gaussians.empty(2)
    assert len(e) == 0 and e.sh.shape == (0, 9, 3) and e.sh_degree == 2


# ------------------------------------------------------------------------------------ spherical harmonics
def _sphere_quadrature() -> tuple[torch.Tensor, torch.Tensor]:
    """Gauss-Legendre in cos(theta) x uniform phi: exact for polynomials of degree <= 7 on the sphere."""
    x, w = np.polynomial.legendre.leggauss(8)
    phi = np.arange(16) * (2 * np.pi / 16)
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct * ct)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    weights = (w[:, None] * np.full_like(ph, 2 * np.pi / 16)).reshape(-1)
    return torch.from_numpy(dirs), torch.from_numpy(weights)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_basis_is_orthonormal_on_the_sphere(degree: int) -> None:
    dirs, w = _sphere_quadrature()
    B = sh_basis(dirs, degree)
    assert B.shape == (dirs.shape[0], num_sh_bases(degree))
    gram = (B * w[:, None]).T @ B
    torch.testing.assert_close(gram, torch.eye(B.shape[1], dtype=F64), atol=1e-12, rtol=0)
    torch.testing.assert_close(B, sh_basis_reference(dirs, degree), atol=1e-14, rtol=0)


def test_sh_degree_helpers() -> None:
    assert [num_sh_bases(d) for d in range(4)] == [1, 4, 9, 16]
    assert [sh_degree_from_bases(k) for k in (1, 4, 9, 16)] == [0, 1, 2, 3]
    for k in (0, 2, 6, 25):
        with pytest.raises(ValueError):
            sh_degree_from_bases(k)
    with pytest.raises(ValueError):
        num_sh_bases(4)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_colors_match_reference_and_clamp(degree: int) -> None:
    g = random_gaussians(64, degree, 9, dtype=F64)
    center = torch.tensor([0.5, -3.0, 1.0], dtype=F64)
    d = g.means - center
    d = d / d.norm(dim=-1, keepdim=True)
    want = ((sh_basis_reference(d, degree)[:, :, None] * g.sh).sum(1) + 0.5).clamp_min(0)
    got = g.colors(center)
    torch.testing.assert_close(got, want, atol=1e-12, rtol=0)
    assert (got == 0).any()  # some colours are clamped at 0 with these coefficients
    torch.testing.assert_close(eval_sh_colors(g.sh, d), want, atol=1e-12, rtol=0)
    # a float64 camera centre does not promote float32 Gaussians' colours
    g32 = g.to(dtype=torch.float32)
    c32 = g32.colors(center)
    assert c32.dtype == torch.float32
    torch.testing.assert_close(c32.double(), want, atol=1e-5, rtol=0)


def test_rgb_to_sh_dc_gives_that_colour_everywhere() -> None:
    rgb = torch.tensor([[0.1, 0.5, 0.9], [1.0, 0.0, 0.25]], dtype=F64)
    sh = torch.zeros(2, 16, 3, dtype=F64)
    sh[:, 0] = rgb_to_sh_dc(rgb)
    dirs = torch.nn.functional.normalize(
        torch.randn(2, 3, dtype=F64, generator=torch.Generator().manual_seed(0)), dim=-1
    )
    torch.testing.assert_close(eval_sh_colors(sh, dirs), rgb, atol=1e-12, rtol=0)
