"""The Gaussians container: a set of 3D Gaussians, each knowing its owner particle."""

from __future__ import annotations

from dataclasses import dataclass, fields
from os import PathLike

import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix
from torch import Tensor

from particlesplat.core.sh import eval_sh_colors, sh_degree_from_bases
from particlesplat.formats.ply import BACKGROUND_OWNER, MAX_OWNER, read_ply, write_ply

__all__ = ["BACKGROUND_OWNER", "MAX_OWNER", "Gaussians", "quats_to_rotations"]
_FLOAT_FIELDS = ("means", "quats", "scales", "opacities", "sh")


def quats_to_rotations(quats: Tensor) -> Tensor:
    """(N, 4) wxyz quaternions of any norm -> (N, 3, 3) rotations; a zero quaternion gives the identity.

    The quaternion is first divided by its largest |component| so that tiny (< 1e-12) or huge
    norms normalise exactly instead of under- or overflowing inside kornia's normalisation.
    """
    peak = quats.detach().abs().amax(-1, keepdim=True)
    return quaternion_to_rotation_matrix(quats / torch.where(peak > 0, peak, torch.ones_like(peak)))


class BadGaussiansError(ValueError):
    """Gaussians the renderer refuses (:meth:`Gaussians.check`): a non-finite or negative value, an owner out of range.
    A bug where the library made them; a command that decoded them from a user's checkpoint or scene turns it into
    one line naming that input (:func:`particlesplat.core.errors.blame`); training skips the step."""


@dataclass
class Gaussians:
    """A set of N 3D Gaussians.

    Attributes:
        means: (N, 3) world metres.
        quats: (N, 4) rotation quaternions, wxyz, normalised on use. A zero quaternion
            means the identity rotation (documented choice; no error, finite gradients).
        scales: (N, 3) standard deviations along the local axes, metres (linear, >= 0).
        opacities: (N,) in [0, 1].
        sh: (N, K, 3) SH coefficients, K = (degree + 1)^2; colour = max(Σ B_k sh_k + 0.5, 0).
        owner: (N,) int64 particle index, -1 for background.
    """

    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    sh: Tensor
    owner: Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expect = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "owner": (n,)}
        for name, shape in expect.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise ValueError(f"Gaussians.{name} must have shape {shape}, got {got}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"Gaussians.sh must have shape ({n}, K, 3), got {tuple(self.sh.shape)}")
        sh_degree_from_bases(self.sh.shape[1])
        if self.owner.dtype != torch.int64:
            self.owner = self.owner.to(torch.int64)

    def check(self, where: str = "Gaussians") -> None:
        """BadGaussiansError naming ``where``, the field and the first bad Gaussian unless every value is finite,
        the scales and opacities are >= 0 and every owner is -1 or a particle index 0..:data:`MAX_OWNER`.
        One device synchronisation when all is well."""
        checks = [torch.isfinite(getattr(self, name)).all() for name in _FLOAT_FIELDS]
        checks += [
            (self.scales >= 0).all(),
            (self.opacities >= 0).all(),
            ((self.owner >= BACKGROUND_OWNER) & (self.owner <= MAX_OWNER)).all(),
        ]
        if bool(torch.stack(checks).all()):
            return
        for name in _FLOAT_FIELDS:
            bad = ~torch.isfinite(getattr(self, name).detach())
            if bool(bad.any()):
                row = int(bad.reshape(bad.shape[0], -1).any(1).nonzero()[0, 0])
                raise BadGaussiansError(f"{where}: {name}: non-finite value at Gaussian {row}")
        for name in ("scales", "opacities"):
            bad = getattr(self, name).detach() < 0
            if bool(bad.any()):
                row = int(bad.reshape(bad.shape[0], -1).any(1).nonzero()[0, 0])
                raise BadGaussiansError(f"{where}: {name}: negative value at Gaussian {row}")
        row = int(((self.owner < BACKGROUND_OWNER) | (self.owner > MAX_OWNER)).nonzero()[0, 0])
        raise BadGaussiansError(
            f"{where}: owner: {int(self.owner[row])} at Gaussian {row} is neither -1 (background) "
            f"nor a particle index 0..{MAX_OWNER}"
        )

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def empty(
        sh_degree: int = 0, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32
    ) -> Gaussians:
        k = (sh_degree + 1) ** 2
        z = lambda *s: torch.zeros(*s, device=device, dtype=dtype)  # noqa: E731
        return Gaussians(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, k, 3), torch.zeros(0, dtype=torch.int64, device=device))

    @staticmethod
    def cat(parts: list[Gaussians]) -> Gaussians:
        """Concatenate Gaussian sets; SH degrees are raised to the largest one (zero padded)."""
        if not parts:
            raise ValueError("Gaussians.cat needs at least one set")
        k = max(p.sh.shape[1] for p in parts)
        shs = [torch.nn.functional.pad(p.sh, (0, 0, 0, k - p.sh.shape[1])) for p in parts]
        return Gaussians(
            torch.cat([p.means for p in parts]),
            torch.cat([p.quats for p in parts]),
            torch.cat([p.scales for p in parts]),
            torch.cat([p.opacities for p in parts]),
            torch.cat(shs),
            torch.cat([p.owner for p in parts]),
        )

    # ------------------------------------------------------------------ properties
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_bases(self.sh.shape[1])

    @property
    def device(self) -> torch.device:
        return self.means.device

    def rotations(self) -> Tensor:
        """(N, 3, 3) rotation matrices from the (normalised) quaternions."""
        return quats_to_rotations(self.quats)

    def covariances(self) -> Tensor:
        """(N, 3, 3) world covariances R diag(s^2) R^T, metres^2."""
        M = self.rotations() * self.scales[:, None, :]
        return M @ M.transpose(-1, -2)

    def colors(self, camera_center: Tensor) -> Tensor:
        """(N, 3) colours seen from ``camera_center`` (3,) (view direction camera -> mean), in the
        dtype of the Gaussians."""
        dirs = torch.nn.functional.normalize(self.means - camera_center.to(self.means), dim=-1)
        return eval_sh_colors(self.sh, dirs)

    # ------------------------------------------------------------------ subsets and moves
    def _map(self, fn) -> Gaussians:
        return Gaussians(*(fn(getattr(self, f.name)) for f in fields(self)))

    def subset(self, index: Tensor) -> Gaussians:
        """Gaussians selected by a bool mask (N,) or an index tensor (M,)."""
        return self._map(lambda t: t[index])

    def of_owner(self, owners: int | list[int] | Tensor) -> Gaussians:
        """Gaussians whose owner is one of ``owners`` (-1 selects the background)."""
        owners_t = torch.as_tensor(owners, dtype=torch.int64, device=self.device).reshape(-1)
        return self.subset(torch.isin(self.owner, owners_t))

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Gaussians:
        """Move to a device; ``dtype`` converts the float fields (owner stays int64)."""
        return self._map(lambda t: t.to(device=device, dtype=dtype if t.is_floating_point() else None))

    def detach(self) -> Gaussians:
        return self._map(lambda t: t.detach())

    # ------------------------------------------------------------------ .ply I/O
    @staticmethod
    def load_ply(path: str | PathLike) -> Gaussians:
        """Read a standard 3DGS .ply (see :mod:`particlesplat.formats.ply`)."""
        return Gaussians(*read_ply(path))

    def save_ply(self, path: str | PathLike) -> None:
        """Write a standard 3DGS .ply atomically (see :mod:`particlesplat.formats.ply`)."""
        write_ply(self, path)

    @staticmethod
    def load(path: str | PathLike) -> Gaussians:
        """Read any Gaussian file: ``.ply``, ``.compressed.ply``, ``.splat``, ``.spz``, ``.sog`` or an object
        bundle's ``manifest.json`` (see :mod:`particlesplat.formats.splat_files`)."""
        from particlesplat.formats.splat_files import read_gaussians

        return Gaussians(*read_gaussians(path))

    def save(self, path: str | PathLike) -> None:
        """Write in the format ``path``'s extension names (``.ply``, ``.compressed.ply``, ``.splat``, ``.spz``,
        ``.sog``), atomically."""
        from particlesplat.formats.splat_files import write_gaussians

        write_gaussians(self, path)
