"""What a scene generator records about a scene folder beyond its frames (``scene.json``, docs/dataset.md):
where its cameras look (``look_at``, ``distance``), so that the default view, the orbit and ``--look`` follow the
scene's own scale rather than one family's; its family, so that a command without ``--checkpoint`` opens it
with the shipped model of that family; and a pose (a robot's joint angles) that a model's workspace layer may
follow (``model.background.static_pose``)."""

from __future__ import annotations

import math
from os import PathLike
from pathlib import Path

import torch
from torch import Tensor

from particlesplat.core.errors import short_repr, warn_input
from particlesplat.core.jsonfile import MAX_JSON_BYTES, read_json
from particlesplat.core.limits import MIN_DISTANCE_METRES, WORLD_MAX_METRES, rigid_problem
from particlesplat.core.panda_arm import ARM_STATE_KEY, GRIPPER_REACH, NARROW_WORLD_BASE, arm_points, pack_arm_state
from particlesplat.core.viewpoints import Framing
from particlesplat.core.world import SUPPORT_Z, Support
from particlesplat.data.families import DEFAULT_FAMILY, family_of, get_family
from particlesplat.data.folders import TRANSFORMS
from particlesplat.data.pose_ranges import check_limits, generator_range, warn_outside
from particlesplat.data.scene_errors import SceneFormatError

NARROW_GENERATOR = "particlesplat.data.families.robot"  # the narrow robot world's generator, as scene.json names it

SCENE_META = "scene.json"
DATASET_META = "synth.json"  # a dataset folder's settings (particlesplat.data.synth.check_manifest)
MAX_SCENE_META_BYTES = MAX_JSON_BYTES


def read_scene_json(path: Path) -> object:
    """The JSON value of a small metadata file (:func:`particlesplat.core.jsonfile.read_json`, at most
    :data:`MAX_SCENE_META_BYTES`); SceneFormatError names the file when it is too big or not JSON."""
    return read_json(path, MAX_SCENE_META_BYTES, SceneFormatError)


def read_family(path: str | PathLike) -> str | None:
    """The scene family (a registered one, :func:`particlesplat.data.families.family_names`) of a scene folder, a
    split folder or a dataset folder: what the scene's ``scene.json`` records; for a split or dataset folder, what
    every scene below it records (a folder mixing families is refused: one model would encode them all), else the
    dataset's ``synth.json`` (in the folder or the one above it). None when nothing records one."""
    path = Path(path)
    if not path.is_dir():
        return None
    own = path / SCENE_META
    if own.is_file():
        family = family_of(read_scene_json(own), str(own))
        if family is not None:
            return family
    found: dict[str, Path] = {}
    for meta in _scene_metas(path):
        family = family_of(read_scene_json(meta), str(meta))
        if family is not None:
            found.setdefault(family, meta)
    if len(found) > 1:
        (a, pa), (b, pb) = sorted(found.items())[:2]
        raise SceneFormatError(
            f"{path}: mixes scene families ({pa} is {a}, {pb} is {b}); one model encodes every scene of a "
            "folder: give scenes of one family, or --checkpoint to choose the model"
        )
    if found:
        return next(iter(found))
    for meta in (path / DATASET_META, path.parent / DATASET_META):
        if meta.is_file():
            family = family_of(read_scene_json(meta), str(meta))
            if family is not None:
                return family
    return None


def _scene_metas(folder: Path) -> list[Path]:
    """The ``scene.json`` of every scene folder below ``folder`` (a split: its scenes; a dataset: its splits'
    scenes), hidden folders left out."""
    metas = []
    for child in sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if (child / SCENE_META).is_file():
            metas.append(child / SCENE_META)
        elif not (child / TRANSFORMS).is_file():
            metas += [
                g / SCENE_META
                for g in sorted(child.iterdir())
                if g.is_dir() and not g.name.startswith(".") and (g / SCENE_META).is_file()
            ]
    return metas


def default_checkpoint(path: str | PathLike | None) -> Path:
    """The shipped model for the scenes at ``path`` (:func:`read_family`; the default family's model when no family
    is recorded): what every command opens when ``--checkpoint`` is not given."""
    family = read_family(path) if path is not None else None
    return get_family(family or DEFAULT_FAMILY).shipped_model_path()


def read_framing(folder: str | PathLike) -> Framing | None:
    """The framing ``folder/scene.json`` records: ``look_at`` (3 numbers, world metres) and, when present,
    ``distance`` (metres, > 0). None when the folder has no scene.json or it records no ``look_at`` (the
    cameras alone then frame the scene). A robot scene's arm (:func:`read_arm_state`) and its table top's corners
    (``table_half_extent``) are the framing's ``keep``: the points its default view must show. SceneFormatError
    names the file and the key of a bad value."""
    path = Path(folder) / SCENE_META
    if not path.is_file():
        return None
    meta = read_scene_json(path)
    if not isinstance(meta, dict) or meta.get("look_at") is None:
        return None
    look_at = meta["look_at"]
    if not (isinstance(look_at, list) and len(look_at) == 3 and all(_finite(v) for v in look_at)):
        raise SceneFormatError(f"{path}: key 'look_at' must be 3 finite numbers (metres), got {short_repr(look_at)}")
    if max(abs(float(v)) for v in look_at) > WORLD_MAX_METRES:
        raise SceneFormatError(f"{path}: key 'look_at' is beyond {WORLD_MAX_METRES:g} m from the origin")
    distance = meta.get("distance")
    if distance is not None and not (_finite(distance) and MIN_DISTANCE_METRES <= distance <= WORLD_MAX_METRES):
        raise SceneFormatError(
            f"{path}: key 'distance' must be a number of metres in [{MIN_DISTANCE_METRES:g}, {WORLD_MAX_METRES:g}], "
            f"got {short_repr(distance)}"
        )
    state = read_arm_state(folder)  # a robot scene: its default view shows the arm whole, and the table's top
    arm = [] if state is None else [(float(p[0]), float(p[1]), float(p[2])) for p in arm_points(state)]
    keep = tuple([*arm, *_table_corners(meta)]) if arm else ()
    return Framing(
        (float(look_at[0]), float(look_at[1]), float(look_at[2])),
        None if distance is None else float(distance),
        str(path),
        keep,
    )


def _table_half(meta: dict) -> tuple[float, float] | None:
    """scene.json's ``table_half_extent``: the table top's half extents (x, y metres) about the origin; None when
    the key is absent or not two positive numbers below 10 m."""
    half = meta.get("table_half_extent")
    if not (isinstance(half, list) and len(half) == 2 and all(_finite(v) and 0 < v < 10 for v in half)):
        return None
    return float(half[0]), float(half[1])


def _table_corners(meta: dict) -> list[tuple[float, float, float]]:
    """The corners of a table top centred on the origin at z = 0, from scene.json's ``table_half_extent`` (none
    when it records no table)."""
    half = _table_half(meta)
    if half is None:
        return []
    hx, hy = half
    return [(sx * hx, sy * hy, 0.0) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]


def read_support(folder: str | PathLike | None) -> Support:
    """What objects rest on in the scene at ``folder`` (:class:`particlesplat.core.world.Support`): the table top its
    ``scene.json`` records (``table_half_extent``) with the floor its family's
    :attr:`~particlesplat.data.families.Family.table_height` below it; a plain floor at the support surface's height
    when it records no table (or its family none), or there is no scene.json."""
    path = None if folder is None else Path(folder) / SCENE_META
    if path is None or not path.is_file():
        return Support()
    meta = read_scene_json(path)
    if not isinstance(meta, dict):
        return Support()
    half = _table_half(meta)
    family = family_of(meta, str(path))
    height = get_family(family or DEFAULT_FAMILY).table_height
    if half is None or height is None:
        return Support()
    return Support(half, SUPPORT_Z - height)


def _scene_value(folder: str | PathLike, key: str) -> tuple[Path, object] | None:
    """(path of ``folder/scene.json``, its value under ``key``), or None when there is no scene.json or it has no
    such key (or null)."""
    path = Path(folder) / SCENE_META
    if not path.is_file():
        return None
    meta = read_scene_json(path)
    if not isinstance(meta, dict) or meta.get(key) is None:
        return None
    return path, meta[key]


def read_pose(folder: str | PathLike, key: str, dims: int) -> list[float] | None:
    """The pose ``folder/scene.json`` records under ``key`` (``model.background.static_pose``: a robot's joint
    angles), a list of ``dims`` finite numbers. None when the folder has no scene.json or it lacks the key.
    SceneFormatError names the file and the key of a value of another length or type.

    The key :data:`~particlesplat.core.panda_arm.ARM_STATE_KEY` is the robot state packed from what the scene
    records of the robot (:func:`read_arm_state`)."""
    if key == ARM_STATE_KEY:
        state = read_arm_state(folder)
        if state is not None and len(state) != dims:
            raise SceneFormatError(
                f"{Path(folder) / SCENE_META}: the robot state has {len(state)} numbers, the model reads {dims}"
            )
        return state
    found = _scene_value(folder, key)
    if found is None:
        return None
    path, value = found
    if not (isinstance(value, list) and len(value) == dims and all(_finite(v) for v in value)):
        raise SceneFormatError(f"{path}: key {key!r} must be {dims} finite numbers, got {short_repr(value)}")
    pose = [float(v) for v in value]
    check_limits(pose, key, str(path))  # beyond the robot's joint limits: no pose of the robot
    return pose


def scene_pose(
    folder: str | PathLike, key: str, dims: int, ranges: dict[str, dict[str, list[float]]] | None = None
) -> Tensor | None:
    """The pose (D,) a model that follows one (``model.background.static_pose`` ``key`` of ``dims`` numbers; "" = none)
    reads for the scene at ``folder``: what its scene.json records. None for a model that follows none, and, with
    an InputWarning (the layer then holds the training scenes' mean pose), for a scene that records none.
    ``ranges``: the model's ``input_ranges``; a pose outside its trained range is warned about
    (:mod:`particlesplat.data.pose_ranges`; a model that records none: its generator's range)."""
    if not key:
        return None
    pose = read_pose(folder, key, dims)
    if pose is not None and key != ARM_STATE_KEY:  # the arm's state is read by exact kinematics, not learned
        trained = (ranges or {}).get(key) or generator_range(key)
        warn_outside(pose, key, trained, str(Path(folder) / SCENE_META))
    if pose is None:
        warn_input(
            f"{Path(folder) / SCENE_META}: no key {key!r}: the model's workspace layer follows that pose; it holds "
            "the training scenes' mean pose instead"
        )
        return None
    return torch.tensor(pose)


def read_arm_state(folder: str | PathLike) -> list[float] | None:
    """What ``folder/scene.json`` says of the robot, packed (:func:`~particlesplat.core.panda_arm.pack_arm_state`):
    ``arm_joints_rad`` (required: None without it), ``robot_base`` (default robosuite's, or the narrow world's for
    its scenes that predate the key) and ``gripper`` (one of :data:`~particlesplat.core.panda_arm.GRIPPER_REACH`;
    absent: the largest). SceneFormatError names the file and the key of a bad value (a gripper it does not know
    is named, never taken for the largest in silence)."""
    joints = read_pose(folder, "arm_joints_rad", 7)
    if joints is None:
        return None
    base = read_robot_base(folder)
    if base is None and _scene_value(folder, "world") is None:
        generator = _scene_value(folder, "generator")
        if generator is not None and generator[1] == NARROW_GENERATOR:  # its base was not recorded, but is known
            base = [list(row) for row in NARROW_WORLD_BASE]
    found = _scene_value(folder, "gripper")
    gripper = None
    if found is not None:
        path, value = found
        if not isinstance(value, str) or value.lower() not in GRIPPER_REACH:
            raise SceneFormatError(
                f"{path}: key 'gripper' is {short_repr(value)}, not a gripper this program knows "
                f"({', '.join(GRIPPER_REACH)})"
            )
        gripper = value
    return pack_arm_state(joints, base, gripper)


def read_robot_base(folder: str | PathLike) -> list[list[float]] | None:
    """The robot base's pose ``folder/scene.json`` records under ``robot_base`` (4 x 4, base to world, metres),
    or None when the folder has no scene.json or it lacks the key. SceneFormatError names the file and the key
    of a value that is not 4 rows of 4 finite numbers or not a rigid pose within the world
    (:func:`particlesplat.core.limits.rigid_problem`: an orthonormal rotation with det +1, the last row 0 0 0 1, a
    translation within 1e5 m)."""
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
    problem = rigid_problem(value)  # the check camera poses get: no scale, skew or mirror; within the world
    if problem:
        raise SceneFormatError(f"{path}: key 'robot_base' {problem}")
    return [[float(v) for v in row] for row in value]


def _finite(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) < 1e6
