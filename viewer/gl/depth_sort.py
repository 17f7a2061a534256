"""Front-to-back order of the Gaussians a camera sees, on the CPU (numpy) or on a CUDA GPU (torch).

Every new camera re-sorts every visible Gaussian by float32 camera z. On an H100 machine ``particlesplat bench
viewer`` measured the sort of 100k Gaussians at 4.5 ms with numpy on its CPU and 0.7 ms with torch on the GPU,
the indices copied back included (docs/on-a-gpu.md). Both orders are by increasing z, ties by increasing index;
tests compare them.
"""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np
import torch

from particlesplat.rendering.depth_order import depth_order as sort_by_depth

SortDevice = Literal["auto", "cpu", "cuda"]
SORT_DEVICES: tuple[str, ...] = get_args(SortDevice)


def depth_order(index: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Sort Gaussians front to back: index (M,) int, z (M,) float32 camera depths -> (M,) int32 indices by
    increasing z, ties by increasing index (:func:`particlesplat.rendering.depth_order.depth_order`: one packed
    int64 key a Gaussian, ~10x faster than a stable argsort of z)."""
    return sort_by_depth(np.ascontiguousarray(z, np.float32), np.asarray(index, np.int64)).astype(np.int32)


def resolve_sort_device(choice: SortDevice) -> torch.device | None:
    """The torch device that sorts for ``choice``, or None for numpy on the CPU: ``auto`` takes CUDA where
    torch sees a GPU."""
    if choice not in SORT_DEVICES:
        raise ValueError(f"sort device must be one of {SORT_DEVICES}, got {choice!r}")
    if choice == "cpu" or (choice == "auto" and not torch.cuda.is_available()):
        return None
    if choice == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("sort device cuda: torch sees no CUDA GPU; use cpu or auto")
    return torch.device("cuda")


class DepthSorter:
    """Sorts a fixed point set (the visible Gaussians' means) for any camera.

    ``device`` None sorts with :func:`depth_order` (numpy); a torch device keeps the points there and sorts
    with a stable ``torch.sort`` (the same order: the kept indices are increasing, so ties stay by index).
    """

    def __init__(self, device: torch.device | None = None) -> None:
        self.device = device
        self._means: np.ndarray | torch.Tensor = np.zeros((0, 3), np.float32)
        self._index: np.ndarray | torch.Tensor = np.zeros(0, np.int64)

    def set_points(self, means: np.ndarray, index: np.ndarray) -> None:
        """means: (M, 3) float32 world metres of the Gaussians that may be drawn; index: (M,) increasing int,
        their indices in the renderer's data. Held where the sort runs."""
        means, index = np.ascontiguousarray(means, np.float32), np.asarray(index, np.int64)
        if self.device is None:
            self._means, self._index = means, index
        else:
            self._means, self._index = torch.from_numpy(means).to(self.device), torch.from_numpy(index).to(self.device)

    def order(self, z_row: np.ndarray, near: float, far: float) -> np.ndarray:
        """(K,) int32 indices of the points with near < z < far, front to back. z_row: (4,) the world-to-camera
        matrix's z row (z = z_row[:3] . x + z_row[3])."""
        r = np.asarray(z_row, np.float32)
        if isinstance(self._means, np.ndarray):
            z = self._means @ r[:3] + r[3]
            keep = (z > near) & (z < far)
            return depth_order(np.asarray(self._index)[keep], z[keep])
        zt = self._means @ torch.from_numpy(r[:3]).to(self.device) + float(r[3])
        keep = (zt > near) & (zt < far)
        ranks = torch.sort(zt[keep], stable=True).indices
        return self._index[keep][ranks].to(torch.int32).cpu().numpy()
