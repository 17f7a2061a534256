"""Demonstrations on disk: one ``.npz`` per episode in a folder with a ``collect.json`` manifest.

Layout (format :data:`FORMAT_VERSION`; T decisions, V = 2 views of H x W pixels, K objects)::

    DIR/collect.json              {"format": "particlesplat-policy-episodes", "format_version", "task", "split",
                                   "seed", "resolution", "cameras"}: what every episode of the folder shares
    DIR/episode_NNNNN.npz         one episode, written to a temporary name and renamed when complete

Arrays of an episode file (float64 unless said; world metres and radians, robosuite's frame; quaternions w x y z):

=========================  ===============  =====================================================================
name                       shape            what
=========================  ===============  =====================================================================
``rgb``                    (T, V, H, W, 3)  uint8, each view at each decision
``depth``                  (T, V, H, W)     float32 planar depth, metres (0: nothing)
``masks``                  (T, V, H, W)     uint8 instance ids (object k + 1; 0: table, goal pad, arm, walls)
``intrinsics``             (V, 3, 3)        pixels (the cameras do not move)
``c2w``                    (V, 4, 4)        camera to world, OpenCV axes (x right, y down, z forward)
``joints``                 (T, 7)           the arm's joint angles when deciding
``fingers``                (T, 2)           the gripper's finger joints, metres
``gripper``                (T,)             the gripper's command when deciding (1 open, 0 closed)
``eef``                    (T, 7)           the grasp point (3) and the hand's quaternion (4)
``keypose``                (T, 8)           the keypose taken: position (3), quaternion (4), gripper (1 / 0)
``object_positions``       (T, K, 3)        the objects' body origins
``object_quaternions``     (T, K, 4)        their orientations
``object_boxes``           (T, K, 2, 3)     their axis-aligned boxes' min and max corners (from their geoms)
``sim_time``               (T,)             the simulator's clock, seconds
``final_joints``           (7,)             after the last keypose (likewise ``final_fingers`` (2,),
                                            ``final_eef`` (7,), ``final_object_positions`` (K, 3),
                                            ``final_object_quaternions`` (K, 4), ``final_object_boxes``
                                            (K, 2, 3))
``goal``                   (3,)             the centre of the goal pad's top (NaN without a goal)
``meta``                   ()               a JSON object: task, split, seed, index, success, reached, steps,
                                            wall and simulated seconds, goal_radius, goal_rgba, robot_base (4 x 4), the
                                            gripper, lights and surfaces, and per object its kind, role,
                                            half size (primitives), colour and texture
=========================  ===============  =====================================================================

Images and masks are stored compressed. :func:`read_episode` reads a file back, checking every array's presence,
shape and type against the others (one line naming the file and the array otherwise).
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import UserError, one_line

FORMAT = "particlesplat-policy-episodes"
FORMAT_VERSION = 1
MANIFEST = "collect.json"
VIEWS = 2

# name -> (dtype kind, shape with letters for the episode's sizes)
ARRAYS: dict[str, tuple[str, tuple[str | int, ...]]] = {
    "rgb": ("u1", ("T", VIEWS, "H", "W", 3)),
    "depth": ("f4", ("T", VIEWS, "H", "W")),
    "masks": ("u1", ("T", VIEWS, "H", "W")),
    "intrinsics": ("f8", (VIEWS, 3, 3)),
    "c2w": ("f8", (VIEWS, 4, 4)),
    "joints": ("f8", ("T", 7)),
    "fingers": ("f8", ("T", 2)),
    "gripper": ("f8", ("T",)),
    "eef": ("f8", ("T", 7)),
    "keypose": ("f8", ("T", 8)),
    "object_positions": ("f8", ("T", "K", 3)),
    "object_quaternions": ("f8", ("T", "K", 4)),
    "object_boxes": ("f8", ("T", "K", 2, 3)),
    "sim_time": ("f8", ("T",)),
    "final_joints": ("f8", (7,)),
    "final_fingers": ("f8", (2,)),
    "final_eef": ("f8", (7,)),
    "final_object_positions": ("f8", ("K", 3)),
    "final_object_quaternions": ("f8", ("K", 4)),
    "final_object_boxes": ("f8", ("K", 2, 3)),
    "goal": ("f8", (3,)),
}
META_KEYS = ("task", "split", "seed", "index", "success", "steps", "objects")
MAX_META_BYTES = 1 << 20


class EpisodeFormatError(UserError):
    """An episode file or a demonstrations folder that does not hold what this layout says; the message names
    the file and the array or key."""


def episode_name(index: int) -> str:
    return f"episode_{index:05d}.npz"


@dataclass
class Episode:
    """One recorded episode: ``arrays`` (the names of :data:`ARRAYS`, as stored) and ``meta`` (the JSON object)."""

    arrays: dict[str, np.ndarray]
    meta: dict

    @property
    def steps(self) -> int:
        return int(self.arrays["keypose"].shape[0])

    @property
    def success(self) -> bool:
        return bool(self.meta["success"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]


def write_episode(path: Path, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Write an episode (checked against the layout first) to ``path`` atomically: a temporary file beside it,
    renamed when complete."""
    episode = Episode({k: np.asarray(v) for k, v in arrays.items()}, meta)
    check_episode(episode, str(path))
    payload = {k: np.ascontiguousarray(v.astype(np.dtype(ARRAYS[k][0]), copy=False)) for k, v in episode.arrays.items()}
    with atomic_write(path, "wb") as f:
        np.savez_compressed(f, meta=np.array(json.dumps(meta)), **payload)  # type: ignore[arg-type]


def check_episode(episode: Episode, where: str) -> None:
    """EpisodeFormatError naming ``where`` and the array (or meta key) that is missing or whose type or shape
    disagrees with the layout and the episode's own sizes (T, K, H, W)."""
    sizes: dict[str, int] = {}
    for name, (kind, shape) in ARRAYS.items():
        if name not in episode.arrays:
            raise EpisodeFormatError(f"{where}: missing array '{name}'")
        a = episode.arrays[name]
        if a.dtype != np.dtype(kind) and not (a.dtype.kind == np.dtype(kind).kind and a.dtype.kind == "f"):
            raise EpisodeFormatError(f"{where}: array '{name}': expected {np.dtype(kind)}, got {a.dtype}")
        if a.ndim != len(shape):
            raise EpisodeFormatError(f"{where}: array '{name}': expected {len(shape)} dimensions, got shape {a.shape}")
        for axis, (want, have) in enumerate(zip(shape, a.shape, strict=True)):
            if isinstance(want, str):
                want = sizes.setdefault(want, int(have))
            if want != have:
                raise EpisodeFormatError(
                    f"{where}: array '{name}': axis {axis} is {have}, expected {want} (shape {tuple(a.shape)})"
                )
        if a.dtype.kind == "f" and name not in ("goal",) and not np.isfinite(a).all():
            raise EpisodeFormatError(f"{where}: array '{name}': holds values that are not finite")
    missing = [k for k in META_KEYS if k not in episode.meta]
    if missing:
        raise EpisodeFormatError(f"{where}: meta: missing key '{missing[0]}'")
    if not isinstance(episode.meta["objects"], list) or len(episode.meta["objects"]) != sizes["K"]:
        raise EpisodeFormatError(f"{where}: meta: key 'objects' must list the {sizes['K']} objects of its arrays")
    if episode.meta["steps"] != sizes["T"]:
        raise EpisodeFormatError(
            f"{where}: meta: key 'steps' is {episode.meta['steps']!r}, the arrays hold {sizes['T']}"
        )


def read_episode(path: str | os.PathLike) -> Episode:
    """The episode in ``path`` (:func:`write_episode`'s layout), its sizes checked before its arrays are loaded.

    Raises:
        EpisodeFormatError: not a readable ``.npz``, or an array or meta key missing or of the wrong type or shape.
        BudgetError: its arrays would not fit the memory limit.
    """
    from particlesplat.analysis.particle_arrays import npz_headers
    from particlesplat.core.jsonfile import parse_json
    from particlesplat.core.limits import check_memory

    path = Path(path)
    try:
        sizes = npz_headers(path)
    except UserError as e:
        raise EpisodeFormatError(str(e)) from None
    if sizes.get("meta", 0) > MAX_META_BYTES:
        raise EpisodeFormatError(f"{path}: meta: {sizes['meta']:,} bytes, more than {MAX_META_BYTES:,}")
    check_memory(sum(sizes.values()), f"{path}: its arrays")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "meta" not in data.files:
                raise EpisodeFormatError(f"{path}: missing array 'meta'")
            arrays = {n: data[n] for n in data.files if n in ARRAYS}
            text = str(data["meta"])
    except EpisodeFormatError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:
        raise EpisodeFormatError(f"{path}: not a readable .npz file ({one_line(e, 160)})") from None
    meta = parse_json(text, f"{path}: meta", EpisodeFormatError)
    if not isinstance(meta, dict):
        raise EpisodeFormatError(f"{path}: meta: expected a JSON object, got {type(meta).__name__}")
    episode = Episode(arrays, meta)
    check_episode(episode, str(path))
    return episode


def read_episode_meta(path: str | os.PathLike) -> dict:
    """The ``meta`` of an episode file alone (its headers checked, no image loaded)."""
    from particlesplat.analysis.particle_arrays import npz_headers
    from particlesplat.core.jsonfile import parse_json

    path = Path(path)
    try:
        sizes = npz_headers(path)
    except UserError as e:
        raise EpisodeFormatError(str(e)) from None
    if "meta" not in sizes:
        raise EpisodeFormatError(f"{path}: missing array 'meta'")
    if sizes["meta"] > MAX_META_BYTES:
        raise EpisodeFormatError(f"{path}: meta: {sizes['meta']:,} bytes, more than {MAX_META_BYTES:,}")
    try:
        with np.load(path, allow_pickle=False) as data:
            text = str(data["meta"])
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:
        raise EpisodeFormatError(f"{path}: not a readable .npz file ({one_line(e, 160)})") from None
    meta = parse_json(text, f"{path}: meta", EpisodeFormatError)
    if not isinstance(meta, dict) or "success" not in meta:
        raise EpisodeFormatError(f"{path}: meta: expected a JSON object with key 'success'")
    return meta


def read_manifest(folder: str | os.PathLike) -> dict:
    """The folder's ``collect.json`` (a JSON object of this format)."""
    from particlesplat.core.jsonfile import read_json

    path = Path(folder) / MANIFEST
    manifest = read_json(path, error=EpisodeFormatError)
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise EpisodeFormatError(f"{path}: key 'format': not a folder of {FORMAT} (no such key or another value)")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise EpisodeFormatError(
            f"{path}: key 'format_version' is {str(manifest.get('format_version'))[:40]!r}; this program reads "
            f"{FORMAT_VERSION}"
        )
    return manifest


def episode_files(folder: str | os.PathLike) -> list[Path]:
    """The folder's complete episode files, by index."""
    return sorted(Path(folder).glob("episode_[0-9][0-9][0-9][0-9][0-9].npz"))


def read_episodes(folder: str | os.PathLike, successful_only: bool = False) -> tuple[dict, list[Episode]]:
    """The manifest and every episode of a demonstrations folder (only the expert's successes with
    ``successful_only``), in index order."""
    manifest = read_manifest(folder)
    episodes = [read_episode(p) for p in episode_files(folder)]
    return manifest, [e for e in episodes if e.success or not successful_only]
