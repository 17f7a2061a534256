"""What a scene generator records about a scene folder beyond its frames (``scene.json``, docs/dataset.md):
where its cameras look (``look_at``, ``distance``), so that the default view, the orbit and ``--look`` follow the
scene's own scale rather than one family's; its family, so that a command without ``--checkpoint`` opens it
with the shipped model of that family; and a pose (a robot's joint angles) that a model's workspace layer may
follow (``model.bg_static_pose``)."""

from __future__ import annotations

import json
import math
from os import PathLike
from pathlib import Path

import torch
from torch import Tensor

from particlesplat.core.errors import one_line, short_repr, warn_input
from particlesplat.core.viewpoints import Framing
from particlesplat.data.families import family_of
from particlesplat.data.scene import SceneFormatError

SCENE_META = "scene.json"
DATASET_META = "synth.json"  # a dataset folder's settings (particlesplat.data.synth.check_manifest)
MAX_SCENE_META_BYTES = 16 << 20


def _read_json(path: Path) -> object:
    """The JSON value of a small metadata file; SceneFormatError names the file when it is too big or not JSON."""
    size = path.stat().st_size
    if size > MAX_SCENE_META_BYTES:
        raise SceneFormatError(f"{path}: {size} bytes, more than the {MAX_SCENE_META_BYTES} a {path.name} may have")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise SceneFormatError(f"{path}: not valid JSON ({one_line(e, 200)})") from None


def read_family(path: str | PathLike) -> str | None:
    """The scene family (:data:`particlesplat.data.families.FAMILIES`) of a scene folder, a split folder or a
    dataset folder: what the scene's ``scene.json`` records, else the dataset's ``synth.json`` (in the folder or
    the one above it), else the first scene folder's below it. None when nothing records one."""
    path = Path(path)
    if not path.is_dir():
        return None
    candidates = [path / SCENE_META, path / DATASET_META, path.parent / DATASET_META]
    below = sorted(p for p in path.iterdir() if p.is_dir())[:1]
    candidates += [below[0] / SCENE_META] if below else []
    if below:  # a dataset folder: its first split's first scene
        deeper = sorted(p for p in below[0].iterdir() if p.is_dir())[:1]
        candidates += [deeper[0] / SCENE_META] if deeper else []
    for meta in candidates:
        if meta.is_file():
            family = family_of(_read_json(meta))
            if family is not None:
                return family
    return None


def default_checkpoint(path: str | PathLike | None) -> Path:
    """The shipped model for the scenes at ``path`` (:func:`read_family`; the tabletop model when no family is
    recorded): what every command opens when ``--checkpoint`` is not given."""
    from particlesplat.model.io import shipped_model_path

    family = read_family(path) if path is not None else None
    return shipped_model_path(family or "tabletop")


def read_framing(folder: str | PathLike) -> Framing | None:
    """The framing ``folder/scene.json`` records: ``look_at`` (3 numbers, world metres) and, when present,
    ``distance`` (metres, > 0). None when the folder has no scene.json or it records no ``look_at`` (the
    cameras alone then frame the scene). SceneFormatError names the file and the key of a bad value."""
    path = Path(folder) / SCENE_META
    if not path.is_file():
        return None
    meta = _read_json(path)
    if not isinstance(meta, dict) or meta.get("look_at") is None:
        return None
    look_at = meta["look_at"]
    if not (isinstance(look_at, list) and len(look_at) == 3 and all(_finite(v) for v in look_at)):
        raise SceneFormatError(f"{path}: key 'look_at' must be 3 finite numbers (metres), got {short_repr(look_at)}")
    distance = meta.get("distance")
    if distance is not None and not (_finite(distance) and distance > 0):
        raise SceneFormatError(f"{path}: key 'distance' must be a positive number (metres), got {short_repr(distance)}")
    return Framing(
        (float(look_at[0]), float(look_at[1]), float(look_at[2])), None if distance is None else float(distance)
    )


def _scene_value(folder: str | PathLike, key: str) -> tuple[Path, object] | None:
    """(path of ``folder/scene.json``, its value under ``key``), or None when there is no scene.json or it has no
    such key (or null)."""
    path = Path(folder) / SCENE_META
    if not path.is_file():
        return None
    meta = _read_json(path)
    if not isinstance(meta, dict) or meta.get(key) is None:
        return None
    return path, meta[key]


def read_pose(folder: str | PathLike, key: str, dims: int) -> list[float] | None:
    """The pose ``folder/scene.json`` records under ``key`` (``model.bg_static_pose``: a robot's joint angles), a
    list of ``dims`` finite numbers. None when the folder has no scene.json or it lacks the key. SceneFormatError
    names the file and the key of a value of another length or type."""
    found = _scene_value(folder, key)
    if found is None:
        return None
    path, value = found
    if not (isinstance(value, list) and len(value) == dims and all(_finite(v) for v in value)):
        raise SceneFormatError(f"{path}: key {key!r} must be {dims} finite numbers, got {short_repr(value)}")
    return [float(v) for v in value]


def scene_pose(folder: str | PathLike, key: str, dims: int) -> Tensor | None:
    """The pose (D,) a model that follows one (``model.bg_static_pose`` ``key`` of ``dims`` numbers; "" = none)
    reads for the scene at ``folder``: what its scene.json records. None for a model that follows none, and, with
    an InputWarning (the layer then holds the training scenes' mean pose), for a scene that records none."""
    if not key:
        return None
    pose = read_pose(folder, key, dims)
    if pose is None:
        warn_input(
            f"{Path(folder) / SCENE_META}: no key {key!r}: the model's workspace layer follows that pose; it holds "
            "the training scenes' mean pose instead"
        )
        return None
    return torch.tensor(pose)


def read_robot_base(folder: str | PathLike) -> list[list[float]] | None:
    """The robot base's pose ``folder/scene.json`` records under ``robot_base`` (4 x 4, base to world, metres),
    or None when the folder has no scene.json or it lacks the key. SceneFormatError names the file and the key
    of a value that is not 4 rows of 4 finite numbers."""
    found = _scene_value(folder, "robot_base")
    if found is None:
        return None
    path, value = found
    if not (
        isinstance(value, list)
        and len(value) == 4
        and all(isinstance(row, list) and len(row) == 4 and all(_finite(v) for v in row) for row in value)
    ):
        raise SceneFormatError(f"{path}: key 'robot_base' must be 4 rows of 4 finite numbers, got {short_repr(value)}")
    return [[float(v) for v in row] for row in value]


def _finite(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) < 1e6
