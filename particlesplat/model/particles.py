"""Latent particles of one scene: the seam between the model, the edits and the viewer."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.world import SUPPORT_Z

SCENE_FIELDS = ("background", "cameras", "pose", "backdrop", "support_map")  # one per scene, not one per particle
OPTIONAL_FIELDS = ("cameras", "pose", "backdrop", "support_map", "support")  # not tensors, or may be None

# The attributes a user may edit, in the paper's order, with their widths.
EDITABLE = MappingProxyType({"z_p": 2, "z_s": 2, "z_d": 1, "z_e": 1, "z_t": 1})
# What edits set besides them: the height of the surface under each particle's object (a placement sets it).
PLACED = MappingProxyType({"support": 1})


@dataclass
class Particles:
    """The L foreground particles of all context views of one scene, plus the background.

    Particle ``i`` was encoded from context view ``view[i]`` and is lifted along that view's
    rays; its Gaussians get ``owner = i``. All fields are posterior means (or samples).

    Attributes:
        z_p: (L, 2) image-plane position, normalised to [-1, 1] (x right, y down) in its view.
        z_s: (L, 2) image-plane scale (pre-sigmoid; the decoder uses sigmoid(z_s)).
        z_d: (L, 1) depth (pre-sigmoid; d = d_min + sigmoid(z_d) (d_max - d_min)).
        z_e: (L, 1) depth extent (pre-sigmoid; Δ = ½ (d_max - d_min) sigmoid(z_e)).
        z_t: (L, 1) transparency in [0, 1].
        z_f: (L, D) appearance features.
        view: (L,) int64 index of the context view each particle belongs to.
        background: (V, d_bg, h, w) per-view background latent maps (what the per-view background decoder
            reads, ``bg_per_view``).
        cameras: the V context cameras (OpenCV).
        pose: (D,) the scene's pose the workspace layer follows (``bg_static_pose``: a robot's joint angles), or
            None (the layer's mean pose).
        backdrop: (3,) RGB in [0, 1] behind the Gaussians, read from the context views
            (``background.colour_from_views``), or None (the model's learned colour).
        support_map: (4, N, N) top-down RGB and support share of the support surface, read from the context views
            (``background.support_map``: :mod:`particlesplat.model.support_map`), or None.
        support: (L, 1) world height (metres) of the surface each particle's object rests on, where the decoder's
            ``support.clamp`` and ``support.cut`` put that surface for its Gaussians; None: every particle's is the
            shared world's :data:`~particlesplat.core.world.SUPPORT_Z` (as encoded: an object placed on a lower
            surface, such as the floor past a table's edge, gets that surface's height).
    """

    z_p: Tensor
    z_s: Tensor
    z_d: Tensor
    z_e: Tensor
    z_t: Tensor
    z_f: Tensor
    view: Tensor
    background: Tensor
    cameras: list[Camera] = field(default_factory=list)
    pose: Tensor | None = None
    backdrop: Tensor | None = None
    support_map: Tensor | None = None
    support: Tensor | None = None

    @property
    def num(self) -> int:
        return self.z_p.shape[0]

    def support_heights(self) -> Tensor:
        """(L, 1) the height of the surface under each particle (:attr:`support`; SUPPORT_Z where none is set)."""
        if self.support is not None:
            return self.support
        return torch.full((self.num, 1), SUPPORT_Z, dtype=self.z_t.dtype, device=self.z_t.device)

    @classmethod
    def row_fields(cls) -> tuple[str, ...]:
        """The fields with one row per particle: all but the scene's (:data:`SCENE_FIELDS`)."""
        return tuple(f.name for f in fields(cls) if f.name not in SCENE_FIELDS)

    def _rows(self, fn) -> Particles:
        """The particles with ``fn(name, rows)`` of each row field (an unset :attr:`support` stays unset)."""
        return replace(
            self,
            **{name: fn(name, getattr(self, name)) for name in self.row_fields() if getattr(self, name) is not None},
        )

    def cat(self, other: Particles) -> Particles:
        """These particles followed by ``other``'s (moved to this device; the background, cameras and pose stay
        these). The support heights are set on both when either has them."""
        a, b = self, other
        if (a.support is None) != (b.support is None):
            a, b = replace(a, support=a.support_heights()), replace(b, support=b.support_heights())
        return a._rows(lambda name, t: torch.cat([t, getattr(b, name).to(t.device)]))

    def take(self, rows: Tensor | Sequence[int] | slice) -> Particles:
        """The particles ``rows`` (int64 indices, in that order, repeats allowed, or a slice) on the same
        background and cameras."""
        if not isinstance(rows, slice):
            rows = torch.as_tensor(rows, dtype=torch.long, device=self.z_p.device)
        return self._rows(lambda _, t: t[rows])

    def truncate(self, num: int) -> Particles:
        """The first ``num`` particles."""
        return self.take(slice(0, num))

    def _map(self, fn) -> Particles:
        out = {f.name: fn(getattr(self, f.name)) for f in fields(self) if f.name not in OPTIONAL_FIELDS}
        return Particles(
            **out,
            cameras=list(self.cameras),
            pose=None if self.pose is None else fn(self.pose),
            backdrop=None if self.backdrop is None else fn(self.backdrop),
            support_map=None if self.support_map is None else fn(self.support_map),
            support=None if self.support is None else fn(self.support),
        )

    def detach(self) -> Particles:
        return self._map(lambda t: t.detach())

    def clone(self) -> Particles:
        return self._map(lambda t: t.clone())

    def to(self, device: torch.device | str) -> Particles:
        p = self._map(lambda t: t.to(device))
        return replace(p, cameras=[c.to(device) for c in self.cameras])

    def attribute(self, index: int, name: str) -> Tensor:
        """Current value of an editable attribute (:data:`EDITABLE`) or of the support height (:data:`PLACED`) of
        particle ``index``: (width,)."""
        if name in PLACED:
            return self.support_heights()[index]
        if name not in EDITABLE:
            raise KeyError(f"'{name}' is not an editable particle attribute ({', '.join(EDITABLE)})")
        return getattr(self, name)[index]

    def with_attribute(self, index: int, name: str, value) -> Particles:
        """A copy with attribute ``name`` of particle ``index`` set to ``value`` (width,)."""
        current = self.attribute(index, name)
        value_t = torch.as_tensor(value, dtype=current.dtype, device=current.device).reshape(current.shape)
        new = (self.support_heights() if name in PLACED else getattr(self, name)).clone()
        new[index] = value_t
        values: dict[str, Any] = {name: new}
        return replace(self, **values)
