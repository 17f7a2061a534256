"""Objects as units: export one object's Gaussians to a 3DGS ``.ply``, and insert an object of one scene
into another.

An object is a group of drawing particles (:func:`particlesplat.editing.grouping.dense_objects`, numbered
0..K-1 as in ``particlesplat encode``'s ``object`` array). Inserting object k of scene A into scene B
appends a copy of each of its particles to B's particles, re-expressed in one of B's context views: the
particle keeps its appearance (``z_f``, ``z_t``), its depth extent in metres (``z_e``) and its size in
metres (``z_s`` rescaled by focal length, image size and depth); its anchor (``z_p`` at depth d) moves
rigidly with the object. Each of A's context views is matched with the B view that looks at the new place
from the most similar direction, so the surfaces A's views saw face B's views the same way. A particle is
lifted along its own view's rays, so an object seen by B's views from another angle than A's is turned
with them; its centre is then corrected (up to ``iterations`` rigid moves, :func:`particlesplat.editing.move.translate`)
until the decoded object's centre is at the requested point. The new particles are ordinary particles of B:
edits, moves and the object grouping treat them like B's own.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from os import PathLike
from pathlib import Path

import torch
from torch import Tensor

from particlesplat.core.choices import ObjectCentre
from particlesplat.core.errors import OptionError
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.world import SUPPORT_Z
from particlesplat.editing.grouping import arm_state, members_centre
from particlesplat.editing.move import MoveError, translate
from particlesplat.editing.scene_objects import SceneObjects
from particlesplat.model import Particles, ParticleSplat

LATENTS = ("z_e", "z_t", "z_f")  # copied as they are
PLACE_TOLERANCE = 0.002  # metres: centre corrections stop below this


def scene_objects(model: ParticleSplat, particles: Particles, gaussians: Gaussians | None = None) -> Tensor:
    """(P,) int64 object index 0..K-1 of each drawing particle, -1 for the others (as ``particlesplat encode``)."""
    g = model.decode(particles) if gaussians is None else gaussians
    return SceneObjects.group(particles, g, model.config.bg_mask_threshold, arm=arm_state(model, particles)).labels


def object_members(model: ParticleSplat, particles: Particles, index: int) -> list[int]:
    """The particles of object ``index``; ValueError when the scene has no such object."""
    objects = scene_objects(model, particles)
    K = int(objects.max()) + 1 if objects.numel() and bool((objects >= 0).any()) else 0
    if not 0 <= index < K:
        raise OptionError(f"--object {index}: the scene has {K} objects (0..{K - 1})")
    return (objects == index).nonzero().flatten().tolist()


def object_gaussians(model: ParticleSplat, particles: Particles, index: int) -> Gaussians:
    """The Gaussians of object ``index`` (its particles only, no background; owner = particle index)."""
    return model.decode(particles, torch.tensor(object_members(model, particles, index)), background=False)


def export_object_ply(model: ParticleSplat, particles: Particles, index: int, path: str | PathLike) -> Path:
    """Write object ``index``'s Gaussians as a standard 3DGS ``.ply`` (atomically). Returns the path."""
    from particlesplat.formats.ply import write_ply

    path = Path(path)
    write_ply(object_gaussians(model, particles, index).detach().to("cpu"), path)
    return path


def _centre(
    model: ParticleSplat, particles: Particles, members: list[int], method: ObjectCentre, support: float
) -> Tensor:
    """(3,) float64 centre of the object made of ``members`` (:func:`members_centre`; the origin when it draws
    nothing)."""
    centre = members_centre(model, particles, members, support, method)
    return torch.zeros(3, dtype=torch.float64) if centre is None else centre


def _view_directions(particles: Particles, point: Tensor) -> Tensor:
    """(V, 3) unit directions from each context camera to ``point`` (3,)."""
    d = torch.stack([point.double() - c.center.detach().double().cpu() for c in particles.cameras])
    return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def match_views(src: Particles, src_point: Tensor, dst: Particles, dst_point: Tensor) -> list[int]:
    """For each context view of ``src``, the ``dst`` view that sees ``dst_point`` from the most similar
    direction as it sees ``src_point`` (distinct views when dst has as many; maximising the summed cosine)."""
    a, b = _view_directions(src, src_point), _view_directions(dst, dst_point)
    cos = (a @ b.T).tolist()  # (Va, Vb)
    Va, Vb = len(cos), len(cos[0])
    if Va <= Vb and math.perm(Vb, Va) <= 40320:
        best = max(itertools.permutations(range(Vb), Va), key=lambda p: sum(cos[i][p[i]] for i in range(Va)))
        return list(best)
    return [max(range(Vb), key=lambda j: cos[i][j]) for i in range(Va)]


def reexpress(
    src: Particles, members: list[int], dst: Particles, views: list[int], delta: Tensor, model: ParticleSplat
) -> Particles:
    """Copies of ``src``'s particles ``members`` moved by ``delta`` (3,) world metres and re-expressed in
    ``dst``'s context views (particle i goes to view ``views[src.view[i]]``). Returns the new particles as a
    :class:`Particles` on ``dst``'s cameras and background (the per-particle fields only are new).
    Raises :class:`particlesplat.editing.move.MoveError` when a particle would leave the model's depth range or fill
    its new view."""
    cfg = model.config
    delta = torch.as_tensor(delta, dtype=torch.float64).reshape(3)
    rows: dict[str, list[Tensor]] = {k: [] for k in Particles.row_fields() if k != "support"}
    for i in members:
        ca = src.cameras[int(src.view[i])].to("cpu", torch.float64)
        vb = views[int(src.view[i])]
        cb = dst.cameras[vb].to("cpu", torch.float64)
        size_a = torch.tensor([ca.width, ca.height], dtype=torch.float64)
        size_b = torch.tensor([cb.width, cb.height], dtype=torch.float64)
        d_a = cfg.depth_of(src.z_d[i, 0].detach().double().cpu())
        anchor = ca.unproject((src.z_p[i].detach().double().cpu() + 1.0) * 0.5 * size_a, d_a) + delta
        uv, d_b = cb.project(anchor)
        if not cfg.d_min < float(d_b) < cfg.d_max:
            raise MoveError(
                f"particle {i}: at the new place it lies {float(d_b):.2f} m from view {vb}, outside the "
                f"model's range ({cfg.d_min}, {cfg.d_max}) m"
            )
        f_a = torch.stack([ca.fx, ca.fy]).double()
        f_b = torch.stack([cb.fx, cb.fy]).double()
        # half-size in metres = sigmoid(z_s) * size / 2 * d / f, kept
        scale = torch.sigmoid(src.z_s[i].detach().double().cpu()) * (size_a / f_a) * d_a / ((size_b / f_b) * d_b)
        if bool((scale >= 1.0).any()):
            raise MoveError(f"particle {i}: at the new place it would fill view {vb}")
        dtype = dst.z_p.dtype
        rows["z_p"].append((uv / size_b * 2.0 - 1.0).to(dtype))
        rows["z_d"].append(cfg.depth_logit(d_b).reshape(1).to(dtype))
        rows["z_s"].append(torch.logit(scale).to(dtype))
        for name in LATENTS:
            rows[name].append(getattr(src, name)[i].detach().cpu().to(dtype))
        rows["view"].append(torch.tensor(vb, dtype=dst.view.dtype))
    dev = dst.z_p.device
    new = {k: torch.stack(v).to(dev) for k, v in rows.items()}
    return replace(
        dst,
        z_p=new["z_p"],
        z_s=new["z_s"],
        z_d=new["z_d"],
        z_e=new["z_e"],
        z_t=new["z_t"],
        z_f=new["z_f"],
        view=new["view"],
        support=None,  # on the shared support surface until placed
    )


def insert_object(
    model: ParticleSplat,
    dst: Particles,
    src: Particles,
    index: int,
    at: tuple[float, float],
    *,
    method: ObjectCentre = "resting",
    iterations: int = 3,
    support: float = SUPPORT_Z,
) -> tuple[Particles, list[int]]:
    """Insert object ``index`` of ``src`` (scene A) into ``dst`` (scene B) so that its centre lands at
    ``at`` = (x, y) world metres on B's surface there, at height ``support`` (the shared support surface z = 0, or
    the floor below a table: :meth:`particlesplat.core.world.Support.height_at`).

    The centre (``method``, see :func:`particlesplat.editing.grouping.object_centres`) goes to (x, y, z) with z at
    the object's height above its support in A (A's objects rest on the support surface z = 0 of the shared world
    frame) above ``support``; the new particles take ``support`` as the height of the surface under them.
    Returns (B's particles with the object's appended, the new particle indices).
    """
    members = object_members(model, src, index)
    centre_a = _centre(model, src, members, method, SUPPORT_Z)
    target = torch.tensor([float(at[0]), float(at[1]), float(centre_a[2]) + support - SUPPORT_Z], dtype=torch.float64)
    views = match_views(src, centre_a, dst, target)
    n = dst.num
    out = dst.cat(reexpress(src, members, dst, views, target - centre_a, model))
    new = list(range(n, out.num))
    if support != SUPPORT_Z or out.support is not None:
        heights = out.support_heights().clone()
        heights[n:] = support
        out = replace(out, support=heights)
    for _ in range(iterations):
        err = target - _centre(model, out, new, method, support)
        if float(err.norm()) < PLACE_TOLERANCE:
            break
        for i, attrs in translate(out, new, err, model.config).items():
            for name, value in attrs.items():
                out = out.with_attribute(i, name, value)
    return out, new
