"""The depth sort: numpy and torch (the CPU here, a CUDA GPU where there is one) give the same front-to-back
order, ties by index, with the near and far planes applied."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from viewer.gl.depth_sort import DepthSorter, depth_order, resolve_sort_device

pytestmark = pytest.mark.usefixtures("rasterizer")  # every test: fused kernels and torch twin

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def exact_points(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means on a 1/8 m grid and a z row of quarters: every depth is exact in float32, and many tie."""
    rng = np.random.default_rng(seed)
    means = rng.integers(-16, 17, (n, 3)).astype(np.float32) / 8.0
    index = np.sort(rng.choice(4 * n, n, replace=False))
    z_row = np.array([0.25, -0.5, 0.75, 3.0], np.float64)
    return means, index, z_row


@pytest.mark.parametrize("device", DEVICES)
def test_torch_sorts_as_numpy_with_ties_and_planes(device):
    means, index, z_row = exact_points(5000, seed=0)
    z = means @ z_row[:3].astype(np.float32) + np.float32(z_row[3])
    near, far = 1.0, 5.0
    keep = (z > near) & (z < far)
    expect = index[keep][np.lexsort((index[keep], z[keep]))]  # independent: by z, then by index
    assert 0 < keep.sum() < len(z) and len(np.unique(z[keep])) < keep.sum() / 10  # both planes cut; many ties
    numpy_sorter, torch_sorter = DepthSorter(None), DepthSorter(torch.device(device))
    for s in (numpy_sorter, torch_sorter):
        s.set_points(means, index)
    got_numpy, got_torch = numpy_sorter.order(z_row, near, far), torch_sorter.order(z_row, near, far)
    assert got_torch.dtype == got_numpy.dtype == np.int32
    np.testing.assert_array_equal(got_numpy, expect)
    np.testing.assert_array_equal(got_torch, expect)


@pytest.mark.parametrize("device", DEVICES)
def test_torch_order_is_front_to_back_on_random_points(device):
    """Random float depths may round differently on another device: the torch order is still a front-to-back
    order of the same points (to float32 rounding)."""
    rng = np.random.default_rng(1)
    means = rng.uniform(-1, 1, (20000, 3)).astype(np.float32)
    index = np.arange(20000)
    z_row = np.array([0.3, -0.5, 0.81, 3.0])
    s = DepthSorter(torch.device(device))
    s.set_points(means, index)
    got = s.order(z_row, 0.01, 1e10)
    z = means @ z_row[:3].astype(np.float32) + np.float32(z_row[3])
    assert np.array_equal(np.sort(got), index)
    assert float(np.diff(z[got]).min()) >= -1e-6
    np.testing.assert_array_equal(np.sort(z[got]), z[depth_order(index, z)])


def test_sort_device_choice():
    assert resolve_sort_device("cpu") is None
    assert resolve_sort_device("auto") == (torch.device("cuda") if torch.cuda.is_available() else None)
    with pytest.raises(ValueError, match="sort device must be one of"):
        resolve_sort_device("gpu")  # type: ignore[arg-type]
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="torch sees no CUDA GPU"):
            resolve_sort_device("cuda")
