"""What an object bundle (:mod:`particlesplat.formats.bundle`) holds: a scene's Gaussians cut into one part per
particle or per object plus the rest, each with the manifest fields a web viewer needs to move and scale it."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from particlesplat.analysis.particle_arrays import ParticleArrays
from particlesplat.core.errors import OptionError
from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.bundle import REST, weighted_centre

BY = ("particle", "object")


def bundle_header(
    source: str, model_name: str | None, particles=None, context: list[int] | None = None, edited: bool = False
) -> dict[str, Any]:
    """The manifest's scene fields: the scene folder or file, the model, whether edits were applied, the context
    frames and their cameras (``particles.cameras``: K and c2w at the model's resolution, OpenCV axes)."""
    cams = [] if particles is None else particles.cameras
    frames = list(context or range(len(cams)))
    return {
        "scene": source,
        "model": model_name or None,
        "edited": bool(edited),
        "context": [int(f) for f in frames] if cams else [],
        "cameras": [
            {
                "frame": int(frame),
                "width": int(c.width),
                "height": int(c.height),
                "K": c.K.detach().double().cpu().tolist(),
                "c2w": c.c2w.detach().double().cpu().tolist(),
            }
            for frame, c in zip(frames, cams, strict=True)
        ],
        "units": "metres, world +z up, OpenCV cameras (x right, y down, z forward)",
    }


def bundle_parts(
    gaussians: Gaussians, by: str, arrays: ParticleArrays | None
) -> list[tuple[str, Gaussians, dict[str, Any]]]:
    """(name, Gaussians, manifest fields) per part, ``rest`` last; every Gaussian is in exactly one part.

    ``by="particle"``: one part per owner >= 0 the Gaussians hold (``particle_<i>``); ``by="object"``: one part per
    object of ``arrays`` (``object_<k>``, its member particles' Gaussians). ``arrays`` (the model scene's particle
    arrays, None for a Gaussian file) adds each particle's activity, presence (``z_t``), object label and anchor.
    Centre and extent are each part's opacity-weighted mean and standard deviation of its Gaussians (metres).
    """
    g = gaussians.detach().to("cpu")
    owner = g.owner.numpy()
    taken = np.zeros(g.num, dtype=bool)
    parts: list[tuple[str, Gaussians, dict[str, Any]]] = []

    def add(name: str, mask: np.ndarray, info: dict[str, Any]) -> None:
        part = g.subset(torch.from_numpy(mask))
        centre, extent = weighted_centre(part)
        parts.append((name, part, {"kind": name.split("_")[0], **info, "centre": centre, "extent": extent}))
        taken[mask] = True

    if by == "particle":
        for i in sorted(int(o) for o in np.unique(owner[owner >= 0])):
            info: dict[str, Any] = {"index": i, "members": [i]}
            if arrays is not None and i < arrays.num_particles:
                info.update(
                    active=bool(arrays.active[i]),
                    presence=float(arrays.z_t[i, 0]),
                    object=int(arrays.object[i]),
                    anchor=[float(v) for v in arrays.anchor[i]],
                )
            add(f"particle_{i}", owner == i, info)
    elif by == "object":
        if arrays is None:
            raise OptionError("--by object needs a model scene (its particles' objects), not a Gaussian file")
        for k in range(arrays.num_objects):
            members = [int(i) for i in np.flatnonzero(arrays.object == k)]
            info = {
                "index": k,
                "object": k,
                "members": members,
                "active": True,
                "presence": float(arrays.z_t[members, 0].max()) if members else 0.0,
                "object_centre": [float(v) for v in arrays.object_centroid[k]],
            }
            add(f"object_{k}", np.isin(owner, members), info)
    else:
        raise OptionError(f"--by: expected one of {', '.join(BY)}, got {by!r}")
    add(REST, ~taken, {"members": []})
    return parts
