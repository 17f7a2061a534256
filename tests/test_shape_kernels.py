"""The fused shape kernels (``covariance_to_quat_scale`` on the CPU) against their torch twin and finite
differences: generic covariances, flat ones (the per-view background's), round ones (equal eigenvalues, where the
axes are arbitrary and the gradient is damped) and rank-deficient ones."""

from __future__ import annotations

import pytest
import torch

from particlesplat.model.geometry import covariance_to_quat_scale


def factors(n: int = 3000, dtype=torch.float64) -> torch.Tensor:
    gen = torch.Generator().manual_seed(0)
    M = torch.randn(n, 3, 3, generator=gen, dtype=torch.float64) * torch.logspace(-3, 0, 3, dtype=torch.float64)
    M[:200, :, 2] = 0.0  # flat: one variance 0
    M[200:300] = torch.eye(3, dtype=torch.float64) * 0.1  # round: three equal variances
    M[300:400, :, 1] = M[300:400, :, 0]  # two columns alike
    return M.to(dtype)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_kernels_give_the_twins_quaternions_scales_and_gradients(dtype):
    A, B = (factors(dtype=dtype).requires_grad_() for _ in range(2))
    q1, s1 = covariance_to_quat_scale(A, fused=True)
    q0, s0 = covariance_to_quat_scale(B, fused=False)
    assert q1.dtype == dtype and s1.dtype == dtype
    assert (q1 - q0).abs().max() < 1e-9
    # scales to the twin's rounding, relative to each Gaussian's largest (a variance 0 is sqrt of rounding noise)
    assert ((s1 - s0).abs() / s0.amax(-1, keepdim=True)).max() < 1e-8
    gen = torch.Generator().manual_seed(1)
    wq, ws = torch.randn(q1.shape, generator=gen, dtype=dtype), torch.randn(s1.shape, generator=gen, dtype=dtype)
    ((q1 * wq).sum() + (s1 * ws).sum()).backward()
    ((q0 * wq).sum() + (s0 * ws).sum()).backward()
    assert torch.isfinite(A.grad).all()
    rel = (A.grad - B.grad).abs().amax((-1, -2)) / B.grad.abs().amax((-1, -2)).clamp_min(1e-30)
    assert rel.max() < 1e-5 and rel.median() < 1e-10


def test_the_backward_is_the_derivative():
    """Central differences of a loss of both outputs, float64, on generic factors (distinct variances)."""
    gen = torch.Generator().manual_seed(2)
    M = torch.randn(40, 3, 3, generator=gen, dtype=torch.float64).requires_grad_()
    wq, ws = (
        torch.randn(40, 4, generator=gen, dtype=torch.float64),
        torch.randn(40, 3, generator=gen, dtype=torch.float64),
    )

    def loss(x: torch.Tensor) -> torch.Tensor:
        q, s = covariance_to_quat_scale(x, fused=True)
        return (q * wq).sum() + (s * ws).sum()

    loss(M).backward()
    numeric = torch.zeros_like(M)
    h = 1e-6
    with torch.no_grad():
        for idx in range(M.numel()):
            d = torch.zeros(M.numel(), dtype=torch.float64)
            d[idx] = h
            d = d.reshape(M.shape)
            numeric.view(-1)[idx] = (loss(M + d) - loss(M - d)) / (2 * h)
    assert torch.allclose(M.grad, numeric, rtol=1e-5, atol=1e-6)


def test_batch_shapes_threads_and_empty():
    M = factors(600).reshape(2, 300, 3, 3)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = covariance_to_quat_scale(M, fused=True)
        torch.set_num_threads(2)
        two = covariance_to_quat_scale(M, fused=True)
    finally:
        torch.set_num_threads(before)
    assert one[0].shape == (2, 300, 4) and one[1].shape == (2, 300, 3)
    assert torch.equal(one[0], two[0]) and torch.equal(one[1], two[1])  # each Gaussian on its own: bit for bit
    q, s = covariance_to_quat_scale(torch.zeros(0, 5, 3, 3), fused=True)
    assert q.shape == (0, 5, 4) and s.shape == (0, 5, 3)
