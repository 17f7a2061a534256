"""Shared checks of ``particlesplat.render`` against the float64 brute force: test Gaussians, cameras,
random projection weights, and the comparison of images and gradients."""

from __future__ import annotations

import math

import torch
from reference_render import ReferenceResult, reference_render

from particlesplat import Camera, Gaussians, render

F32, F64 = torch.float32, torch.float64
FIELDS = ("means", "quats", "scales", "opacities", "sh")
BG = (0.2, 0.3, 0.4)
SH_C0 = 0.5 / math.sqrt(math.pi)


def make(
    means, quats=None, scales=None, opacities=None, sh=None, owner=None, *, dtype=F32, degree: int = 0, seed: int = 0
) -> Gaussians:
    """Gaussians from array-likes; missing fields get defaults (identity, 0.1 m, 0.7, random colours)."""
    means = torch.as_tensor(means, dtype=F64).reshape(-1, 3)
    n = means.shape[0]
    gen = torch.Generator().manual_seed(seed)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=F64).repeat(n, 1) if quats is None else quats
    scales = torch.full((n, 3), 0.1, dtype=F64) if scales is None else scales
    opacities = torch.full((n,), 0.7, dtype=F64) if opacities is None else opacities
    if sh is None:
        sh = torch.randn(n, (degree + 1) ** 2, 3, generator=gen, dtype=F64) * 0.5
    owner = torch.zeros(n, dtype=torch.int64) if owner is None else owner
    as_t = lambda x, s: torch.as_tensor(x, dtype=F64).reshape(s).to(dtype)  # noqa: E731
    return Gaussians(
        means.to(dtype),
        as_t(quats, (n, 4)),
        as_t(scales, (n, 3)),
        as_t(opacities, (n,)),
        torch.as_tensor(sh, dtype=F64).reshape(n, -1, 3).to(dtype),
        torch.as_tensor(owner, dtype=torch.int64).reshape(n),
    )


def pinhole(width: int = 37, height: int = 23, f: float = 30.0) -> Camera:
    """float64 camera at the origin looking down +z, focal ``f`` px, centred principal point."""
    K = torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]], dtype=F64)
    return Camera(K, torch.eye(4, dtype=F64), width, height)


def random_scene(seed: int, n: int, degree: int, width: int = 37, height: int = 23) -> tuple[Gaussians, Camera]:
    """Random float32 Gaussians in front of a look-at camera (float64 camera)."""
    gen = torch.Generator().manual_seed(seed)
    cam = Camera.look_at(
        (0.3 * seed - 0.4, -4.0, 1.0), (0.0, 0.1, 0.0), fov_y_deg=45.0, width=width, height=height, dtype=F64
    )
    means = (torch.rand(n, 3, generator=gen, dtype=F64) - 0.5) * 3.0
    quats = torch.randn(n, 4, generator=gen, dtype=F64)
    scales = torch.exp(torch.randn(n, 3, generator=gen, dtype=F64) * 0.5) * 0.12
    opac = 0.05 + 0.9 * torch.rand(n, generator=gen, dtype=F64)
    sh = torch.randn(n, (degree + 1) ** 2, 3, generator=gen, dtype=F64) * 0.4
    owner = torch.randint(-1, 4, (n,), generator=gen)
    return make(means, quats, scales, opac, sh, owner), cam


def leaves(gs: Gaussians, dtype: torch.dtype) -> tuple[dict[str, torch.Tensor], Gaussians]:
    """Fresh leaf tensors (requires_grad) of ``gs`` in ``dtype`` and the Gaussians built from them."""
    d = {f: getattr(gs, f).detach().to(dtype).clone().requires_grad_(True) for f in FIELDS}
    return d, Gaussians(**d, owner=gs.owner.clone())


def weights(h: int, w: int, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random float64 projection weights for rgb (h, w, 3), alpha (h, w) and depth (h, w)."""
    gen = torch.Generator().manual_seed(seed)
    return (
        torch.randn(h, w, 3, generator=gen, dtype=F64),
        torch.randn(h, w, generator=gen, dtype=F64),
        torch.randn(h, w, generator=gen, dtype=F64),
    )


def loss_of(res, wts) -> torch.Tensor:
    """Scalar random projection of rgb, alpha and depth (float64)."""
    return (res.rgb.double() * wts[0]).sum() + (res.alpha.double() * wts[1]).sum() + (res.depth.double() * wts[2]).sum()


def assert_images_close(res, ref: ReferenceResult, atol: float, depth_rtol: float = 0.0) -> None:
    """Max abs error <= atol on rgb, alpha, depth (depth: + depth_rtol * reference depth)."""
    for name in ("rgb", "alpha", "depth"):
        got = getattr(res, name)
        assert torch.isfinite(got).all(), f"{name} has non-finite values"
        want = getattr(ref, name).detach()
        err = (got.double() - want).abs()
        if name == "depth":
            err = err - depth_rtol * want.abs()
        assert err.max().item() <= atol, f"{name}: max abs error {err.max().item():.3e} > {atol:.1e}"


def assert_grads_close(got: dict[str, torch.Tensor], want: dict[str, torch.Tensor], rtol: float, atol: float) -> None:
    """Per field: finite, and |got - want| <= rtol * max|want| + atol."""
    for f in FIELDS:
        g = got[f].grad
        w = want[f].grad
        assert g is not None, f"no gradient for {f}"
        assert torch.isfinite(g).all(), f"non-finite gradient for {f}"
        if w is None:
            w = torch.zeros_like(g, dtype=F64)
        err = (g.double() - w).abs().max().item() if g.numel() else 0.0
        tol = rtol * (w.abs().max().item() if w.numel() else 0.0) + atol
        assert err <= tol, f"grad {f}: max abs error {err:.3e} > {tol:.3e} (max |g| {w.abs().max().item():.3e})"


def check_against_reference(
    gs: Gaussians,
    cam: Camera,
    *,
    atol: float = 1e-5,
    depth_rtol: float = 0.0,
    grads: bool = True,
    check64: bool = True,
    **kw,
) -> ReferenceResult:
    """float32 render vs float64 brute force (outputs and gradients), and the float64 render too.

    ``depth_rtol`` only for depths where float32 cannot hold 1e-5 m (points 1e4 m away)."""
    H, W = cam.height, cam.width
    wts = weights(H, W)
    d_ref, g_ref = leaves(gs, F64)
    ref = reference_render(g_ref, cam, **kw)
    if grads:
        loss_of(ref, wts).backward()
    d32, g32 = leaves(gs, F32)
    res = render(g32, cam.to(dtype=F32), **kw)
    assert res.rgb.dtype == F32 and res.rgb.shape == (H, W, 3)
    assert res.alpha.shape == (H, W) and res.depth.shape == (H, W)
    assert_images_close(res, ref, atol, depth_rtol)
    if grads:
        loss_of(res, wts).backward()
        assert_grads_close(d32, d_ref, rtol=2e-4, atol=1e-6)
    if check64:
        d64, g64 = leaves(gs, F64)
        res64 = render(g64, cam, **kw)
        assert res64.rgb.dtype == F64
        assert_images_close(res64, ref, 1e-9)
        if grads:
            loss_of(res64, wts).backward()
            assert_grads_close(d64, d_ref, rtol=1e-7, atol=1e-10)
    return ref
