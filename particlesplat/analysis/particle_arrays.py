"""Particles as data: the particles of one encoded scene as plain arrays for downstream learners.

:func:`encode_scene_arrays` encodes a scene folder and returns a :class:`ParticleArrays`; ``particlesplat
encode`` writes one ``.npz`` per scene with the same arrays (:meth:`ParticleArrays.save`). For P particles,
K objects and V context views (world metres, +z up, OpenCV cameras):

- ``z_p`` (P, 2), ``z_s`` (P, 2), ``z_d`` (P, 1), ``z_e`` (P, 1), ``z_t`` (P, 1), ``z_f`` (P, D): the posterior
  means of the latents (see :class:`particlesplat.model.Particles`); ``view`` (P,) the context view of each.
- ``anchor`` (P, 3): the world point of ``z_p`` at the particle's depth d (the point an edit moves).
- ``centroid`` (P, 3): the opacity-weighted mean of the particle's Gaussians.
- ``extent`` (P, 3): the opacity-weighted standard deviation of those Gaussians along world x, y, z.
- ``colour`` (P, 3): the opacity-weighted mean of their view-independent (SH degree 0) colour, in [0, 1].
- ``active`` (P,) bool: the particle draws (:func:`drawing_particles`).
- ``object`` (P,) int64: the object of an active particle, 0..K-1 (particles grouped by
  :func:`particlesplat.editing.grouping.particle_objects`, numbered by their smallest particle index); -1 when inactive
  or the robot's.
- ``robot`` (P,) bool: the particle draws the robot (:func:`particlesplat.editing.grouping.robot_particles`: its
  centre lies in the room the arm takes, by the scene's joint angles); never an object. All false for a model that
  reads no robot state.
- ``object_centroid`` (K, 3), ``object_extent`` (K, 3): per object (:func:`object_centres`).
- ``K`` (V, 3, 3), ``c2w`` (V, 4, 4): the context cameras at the model's resolution (pixels; OpenCV).
- ``meta``: a JSON string (model, checkpoint SHA-256, context frames, scene path, resolution, object centre
  method, format version).

Statistics are computed in float64 and stored as float32.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from particlesplat.core.atomic import atomic_path
from particlesplat.core.choices import OBJECT_CENTRES, ObjectCentre
from particlesplat.core.errors import UserError, one_line
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.jsonfile import parse_json
from particlesplat.core.sh import SH_C0
from particlesplat.data.scene import SceneFormatError
from particlesplat.data.scene_meta import read_scene_json
from particlesplat.editing.grouping import (
    arm_state,
    drawing_particles,
    object_centres,
    robot_particles,
    weighted_stats,
)
from particlesplat.editing.move import anchor_points
from particlesplat.editing.scene_objects import SceneObjects
from particlesplat.model import Particles, ParticleSplat

FORMAT_VERSION = 2  # 2: the robot array


LATER_ARRAYS = ("robot",)
"""Arrays a file of an earlier format version lacks; reading one fills them in (no particle the robot's)."""


class ParticleArraysError(UserError):
    """A particle ``.npz`` that cannot be read; the message names the file and the array."""


ARRAY_NAMES = (
    "z_p",
    "z_s",
    "z_d",
    "z_e",
    "z_t",
    "z_f",
    "view",
    "anchor",
    "centroid",
    "extent",
    "colour",
    "active",
    "object",
    "robot",
    "object_centroid",
    "object_extent",
    "K",
    "c2w",
)


@dataclass
class ParticleArrays:
    """The particles of one scene as numpy arrays (shapes and units in the module docstring).

    ``meta`` is a dict here and a JSON string in the ``.npz`` file.
    """

    z_p: np.ndarray
    z_s: np.ndarray
    z_d: np.ndarray
    z_e: np.ndarray
    z_t: np.ndarray
    z_f: np.ndarray
    view: np.ndarray
    anchor: np.ndarray
    centroid: np.ndarray
    extent: np.ndarray
    colour: np.ndarray
    active: np.ndarray
    object: np.ndarray
    robot: np.ndarray
    object_centroid: np.ndarray
    object_extent: np.ndarray
    K: np.ndarray
    c2w: np.ndarray
    meta: dict

    @property
    def num_particles(self) -> int:
        return int(self.z_p.shape[0])

    @property
    def num_objects(self) -> int:
        return int(self.object_centroid.shape[0])

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``.npz`` contents: every array plus ``meta`` as a 0-d unicode string array."""
        out = {name: getattr(self, name) for name in ARRAY_NAMES}
        out["meta"] = np.array(json.dumps(self.meta, sort_keys=True))
        return out

    def save(self, path: str | PathLike) -> Path:
        """Write an uncompressed ``.npz`` atomically (temp file, then rename). Returns the path."""
        path = Path(path)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, **self.arrays())  # type: ignore[arg-type]  # numpy's stub reads ** as its allow_pickle
        return path

    @classmethod
    def load(cls, path: str | PathLike) -> ParticleArrays:
        """Read a ``.npz`` written by :meth:`save` (no pickles); ValueError names the file and the array. The
        arrays' headers are checked first (:func:`npz_headers`): a header declaring more bytes than its member
        holds, or more than the memory limit, is refused before anything is allocated."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such .npz file")
        from particlesplat.core.limits import check_memory

        check_memory(sum(npz_headers(path).values()), f"{path}: its arrays")
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [n for n in (*ARRAY_NAMES, "meta") if n not in data.files and n not in LATER_ARRAYS]
                if missing:
                    raise ParticleArraysError(f"{path}: missing array(s) {', '.join(missing)}")
                values = {n: data[n] for n in ARRAY_NAMES if n in data.files}
                for name in LATER_ARRAYS:  # format 1 has no robot array: no particle was the robot's
                    values.setdefault(name, np.zeros(values["active"].shape, dtype=bool))
                meta = parse_json(str(data["meta"]), f"{path}: meta", ParticleArraysError)
        except ParticleArraysError:
            raise
        except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:  # truncated or not an .npz at all
            raise ParticleArraysError(f"{path}: not a readable .npz file ({one_line(e, 160)})") from e
        if not isinstance(meta, dict):
            raise ParticleArraysError(f"{path}: meta: expected a JSON object, got {type(meta).__name__}")
        return cls(**values, meta=meta)


MAX_META_BYTES = 1 << 20  # the meta array of an .npz this program wrote is a few hundred bytes


def npz_headers(path: str | PathLike) -> dict[str, int]:
    """Array name -> bytes its header declares, for every member of the ``.npz`` at ``path``, read from the zip's
    directory and each member's ``.npy`` header only (no array is loaded). ParticleArraysError names the file
    and the array when a member is not an ``.npy``, is compressed, or declares more bytes than it holds (a lying
    header would otherwise allocate what it claims)."""
    path = Path(path)
    out: dict[str, int] = {}
    try:
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                name = info.filename.removesuffix(".npy")
                with z.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(f)
                    else:
                        raise ValueError(f"array '{name[:80]}': .npy format version {version} is not read")
                    header = f.tell()
                declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if dtype.hasobject or declared > info.file_size - header:
                    raise ParticleArraysError(
                        f"{path}: array '{name[:80]}': its header declares {declared:,} bytes of {dtype}, the file "
                        f"holds {max(info.file_size - header, 0):,}"
                    )
                out[name] = declared
    except ParticleArraysError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, RuntimeError) as e:
        raise ParticleArraysError(f"{path}: not a readable .npz file ({one_line(e, 160)})") from None
    return out


def read_npz_meta(path: str | PathLike) -> dict:
    """The ``meta`` of an ``.npz`` written by :meth:`ParticleArrays.save`, reading its headers
    (:func:`npz_headers`) and the meta member alone; ParticleArraysError names the file."""
    path = Path(path)
    sizes = npz_headers(path)
    missing = [n for n in (*ARRAY_NAMES, "meta") if n not in sizes and n not in LATER_ARRAYS]
    if missing:
        raise ParticleArraysError(f"{path}: missing array(s) {', '.join(missing)}")
    if sizes["meta"] > MAX_META_BYTES:
        raise ParticleArraysError(f"{path}: meta: {sizes['meta']:,} bytes, more than {MAX_META_BYTES:,}")
    try:
        with np.load(path, allow_pickle=False) as data:
            text = str(data["meta"])
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:
        raise ParticleArraysError(f"{path}: not a readable .npz file ({one_line(e, 160)})") from None
    from particlesplat.core.jsonfile import parse_json

    meta = parse_json(text, f"{path}: meta", ParticleArraysError)
    if not isinstance(meta, dict):
        raise ParticleArraysError(f"{path}: meta: expected a JSON object, got {type(meta).__name__}")
    return meta


def file_sha256(path: str | PathLike) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def particle_stats(
    model: ParticleSplat, particles: Particles, gaussians: Gaussians
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Per particle (P of ``particles``, on the CPU): centroid (P, 3) and extent (P, 3) of its Gaussians, their
    colour (P, 3) (opacity-weighted, float64), whether it draws (P,) and whether it draws the robot (P,) bool.
    ``gaussians``: their decode on the CPU; only the particles' own Gaussians count, so a decode without the
    background gives the same numbers."""
    g, p, P = gaussians, particles, particles.num
    centroid, extent, _ = weighted_stats(g.means, g.opacities, g.owner, P)
    dc = (SH_C0 * g.sh[:, 0, :].double() + 0.5).clamp(0.0, 1.0)  # (M, 3) view-independent colour
    fg = (g.owner >= 0) & (g.owner < P)
    w = g.opacities.double()[fg]
    total = torch.zeros(P, dtype=torch.float64).index_add_(0, g.owner[fg], w)
    colour = torch.zeros(P, 3, dtype=torch.float64).index_add_(0, g.owner[fg], w[:, None] * dc[fg])
    colour = torch.where(total[:, None] > 0, colour / torch.where(total > 0, total, 1.0)[:, None], 0.0)
    active = drawing_particles(p, g, model.config.bg_mask_threshold)
    robot = robot_particles(p, g, arm_state(model, p)) & active
    return centroid, extent, colour, active, robot


def particle_arrays(
    model: ParticleSplat,
    particles: Particles,
    gaussians: Gaussians | None = None,
    *,
    object_centre: ObjectCentre = "resting",
    meta: dict | None = None,
    objects: SceneObjects | None = None,
) -> ParticleArrays:
    """The arrays of already-encoded ``particles`` (``gaussians``: their decode with the background, decoded
    here when None). ``meta`` is merged into the recorded metadata. ``objects``: the particles' objects when a
    user regrouped them (an editor's, :meth:`SceneEditor.objects`), else grouped here."""
    if gaussians is None:
        gaussians = model.decode(particles)
    g = gaussians.detach().to("cpu")
    p = particles.detach().to("cpu")
    P = p.num
    centroid, extent, colour, active, robot = particle_stats(model, p, g)
    if objects is None:
        labels = SceneObjects.group(p, g, model.config.bg_mask_threshold, arm=arm_state(model, p)).labels
    else:  # a particle that draws nothing (a removed object's) is in none
        labels = SceneObjects(torch.where(active, objects.labels[:P].cpu(), -1)).dense().labels
    num_objects = int(labels.max()) + 1 if bool((labels >= 0).any()) else 0
    obj_centre, obj_extent = object_centres(g, labels, num_objects, object_centre)
    anchor = anchor_points(p, list(range(P)), model.config).double()
    K = torch.stack([c.K for c in p.cameras]).double()
    c2w = torch.stack([c.c2w for c in p.cameras]).double()
    info = {
        "format_version": FORMAT_VERSION,
        "object_centre": object_centre,
        "resolution": int(model.config.resolution),
        "bg_mask_threshold": float(model.config.bg_mask_threshold),
        "units": "metres, world +z up, OpenCV cameras",
    }
    info.update(meta or {})

    def f32(t: Tensor) -> np.ndarray:
        return t.detach().cpu().to(torch.float32).numpy()

    return ParticleArrays(
        z_p=f32(p.z_p),
        z_s=f32(p.z_s),
        z_d=f32(p.z_d),
        z_e=f32(p.z_e),
        z_t=f32(p.z_t),
        z_f=f32(p.z_f),
        view=p.view.cpu().to(torch.int64).numpy(),
        anchor=f32(anchor),
        centroid=f32(centroid),
        extent=f32(extent),
        colour=f32(colour),
        active=active.numpy().astype(bool),
        object=labels.numpy().astype(np.int64),
        robot=robot.numpy().astype(bool),
        object_centroid=f32(obj_centre).reshape(num_objects, 3),
        object_extent=f32(obj_extent).reshape(num_objects, 3),
        K=f32(K),
        c2w=f32(c2w),
        meta=info,
    )


def encode_scene_arrays(
    model: ParticleSplat,
    scene: str | PathLike,
    context: list[int] | None = None,
    *,
    object_centre: ObjectCentre = "resting",
    meta: dict | None = None,
) -> ParticleArrays:
    """Encode the scene folder ``scene`` with ``model`` from the context frames ``context`` (None = the
    viewer's default, :func:`particlesplat.core.viewpoints.default_context_views`) and return its arrays.

    Example::

        from particlesplat.model import load_model
        from particlesplat.analysis.particle_arrays import encode_scene_arrays
        arrays = encode_scene_arrays(load_model(), "assets/scenes/scene_00000", [4, 16])
        arrays.object_centroid  # (K, 3) metres
    """
    from particlesplat.editing.open_scene import encode_scene

    enc = encode_scene(model, scene, context)
    info = {"scene": str(enc.path), "context": [int(i) for i in enc.context]}
    info.update(meta or {})
    return particle_arrays(model, enc.particles, object_centre=object_centre, meta=info)


# ---------------------------------------------------------------------------- localisation
LOCALISATION_RADII = (0.05, 0.10, 0.15)  # metres


def scene_object_centres(scene_dir: str | PathLike) -> np.ndarray | None:
    """(N, 3) true object centres (world metres) recorded by the scene generator in ``scene.json``
    (``objects[i].center``), or None when the folder has no ``scene.json`` or it lists no objects."""
    path = Path(scene_dir) / "scene.json"
    if not path.is_file():
        return None
    doc = read_scene_json(path)
    objects = doc.get("objects") if isinstance(doc, dict) else None
    if not objects:
        return None
    try:
        centres = np.array([[float(v) for v in o["center"]] for o in objects], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as e:
        raise SceneFormatError(f"{path}: objects[].center: expected 3 numbers per object ({e})") from e
    if centres.shape[1:] != (3,):
        raise SceneFormatError(f"{path}: objects[].center: expected 3 numbers per object")
    from particlesplat.core.limits import WORLD_MAX_METRES

    bad = ~(np.isfinite(centres).all(1) & (np.abs(centres) <= WORLD_MAX_METRES).all(1))
    if bad.any():  # a NaN centre would be scored as a miss
        i = int(np.nonzero(bad)[0][0])
        raise SceneFormatError(
            f"{path}: objects[{i}].center must be 3 finite metres within +-{WORLD_MAX_METRES:g}, got "
            f"{centres[i].tolist()}"
        )
    return centres


def nearest_distances(truth: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """(N,) distance (metres) from each true centre (N, 3) to the nearest predicted centre (K, 3); inf when
    K is 0."""
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    predicted = np.asarray(predicted, dtype=np.float64).reshape(-1, 3)
    predicted = predicted[np.isfinite(predicted).all(1)]  # an object without a centre is no candidate
    if predicted.shape[0] == 0:
        return np.full(truth.shape[0], np.inf)
    return np.linalg.norm(truth[:, None, :] - predicted[None, :, :], axis=-1).min(axis=1)


def localisation_summary(distances) -> dict:
    """{"objects": N, "mean_m", "median_m" (finite distances; inf counts in the shares only),
    "within_0.05", "within_0.1", "within_0.15": share of objects within each radius}."""
    d = np.asarray(list(distances), dtype=np.float64)
    finite = d[np.isfinite(d)]
    out = {
        "objects": int(d.size),
        "mean_m": float(finite.mean()) if finite.size else float("nan"),
        "median_m": float(np.median(finite)) if finite.size else float("nan"),
    }
    for r in LOCALISATION_RADII:
        out[f"within_{r:g}"] = float((d <= r).mean()) if d.size else float("nan")
    return out


def object_localisation(
    model: ParticleSplat, particles: Particles, gaussians: Gaussians, truth: np.ndarray, groups: Tensor | None = None
) -> dict[str, list[float]]:
    """Distance from each true object centre (N, 3) to the nearest object centre of the drawing particles, per
    object centre method (:data:`OBJECT_CENTRES`). gaussians: the scene's decode; groups: its
    :func:`particle_objects` labels (computed when None)."""
    g = gaussians.detach().to("cpu")
    p = particles.detach().to("cpu")
    objects = SceneObjects.group(p, g, model.config.bg_mask_threshold, groups, arm=arm_state(model, p)).labels
    K = int(objects.max()) + 1 if bool((objects >= 0).any()) else 0
    return {m: nearest_distances(truth, object_centres(g, objects, K, m)[0].numpy()).tolist() for m in OBJECT_CENTRES}
