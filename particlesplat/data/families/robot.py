"""The robot-workspace scene family: a Panda arm at a table with household objects, simulated and rendered
headless by MuJoCo from robosuite's asset files (composition in :mod:`.robot_compose`).

A scene: 2-5 objects (robosuite's can, bread, cereal, milk, lemon, bottle, or a textured box or
cylinder) dropped at random positions and yaws on the table and settled by physics; a layout whose objects
touch each other or the arm, or leave the table, is drawn again. The arm stands at its home pose with small
joint offsets (or exactly at home, or a random collision-free pose). Cameras: 21 on an arc about the table (or four
RLBench-style fixed ones). Test scenes also carry ground-truth edits: one object moved on the table, the same
object lifted straight up and removed, rendered from the same cameras (``edits.json`` and
``edits/{move,lift,remove}/``).

World: metres, +z up, z = 0 the table top, origin the table centre; the robot on the +y side.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.vectors import float3, float4
from particlesplat.data.scene_files import write_scene_files

from .robot_assets import assets_dir, import_mujoco
from .robot_compose import (
    ASSET_OBJECTS,
    PANDA_HOME,
    PRIMITIVE_TEXTURES,
    PRIMITIVES,
    CameraPose,
    Composition,
    ObjectSpec,
    compose,
    yaw_quat,
)
from .robot_render import SceneRenderer, Views

CameraRig = Literal["arc", "rlbench"]
ArmPose = Literal["home", "still", "random"]
EditKind = Literal["move", "lift", "remove"]
World = Literal["narrow", "wide"]
WORLDS: tuple[World, ...] = ("narrow", "wide")
CAMERA_RIGS: tuple[CameraRig, ...] = ("arc", "rlbench")
ARM_POSES: tuple[ArmPose, ...] = ("home", "still", "random")
EDIT_KINDS: tuple[EditKind, ...] = ("move", "lift", "remove")

NUM_OBJECTS = (2, 5)
PRIMITIVE_PROB = 0.3  # chance that an object is a textured primitive rather than a robosuite object
BOX_HALF = (0.02, 0.05)  # metres, each half extent
CYLINDER_RADIUS, CYLINDER_HALF_HEIGHT = (0.02, 0.04), (0.025, 0.07)
TABLE_MARGIN = 0.12  # metres: objects stay this far inside the table's edge (in every view's frame)
GAP = 0.015  # metres between objects' footprints (axis-aligned boxes in x, y) after settling
ARM_OFFSET = 0.12  # radians: the home pose's joint offsets are uniform in +-this
SETTLE_SECONDS, SETTLE_MAX_SECONDS, REST_SPEED = 0.4, 2.0, 2e-3  # s, s, m/s and rad/s
MAX_LAYOUT_TRIES = 200

NUM_VIEWS = 21
AZIMUTH_RANGE = (-120.0, 120.0)  # degrees; 0 = the front (-y side), facing the robot
ELEVATION_RANGE = (30.0, 45.0)  # degrees, one per scene
DISTANCE_RANGE = (0.85, 1.0)  # metres from the look-at point, one per scene
LOOK_AT = (0.0, 0.0, 0.05)
FOV_Y_DEG = 40.0
FRONT_VIEW = 10
# RLBench-style fixed cameras (eye, target), in trajectory order: left shoulder, front, right shoulder, overhead
RLBENCH_CAMERAS = {
    "left_shoulder": ((0.55, 0.55, 0.55), (0.0, -0.1, 0.0)),
    "front": ((0.0, -1.1, 0.6), (0.0, 0.0, 0.05)),
    "right_shoulder": ((-0.55, 0.55, 0.55), (0.0, -0.1, 0.0)),
    "overhead": ((0.0, -0.05, 1.25), (0.0, 0.0, 0.0)),
}
MOVE_RANGE = (0.10, 0.20)  # metres on the table
# metres the moved object is lifted by, straight up from where it stood: the first that touches nothing
LIFT_HEIGHTS = (0.15, 0.14, 0.13, 0.12, 0.11, 0.10)
FORMAT_VERSION = 1
GENERATOR = "particlesplat.data.families.robot"


@dataclass(frozen=True)
class RobotSceneConfig:
    """What a robot scene is drawn with: ``cameras`` rig, ``arm`` pose, image ``width`` x ``height`` pixels, and
    ``views`` on the arc (the fixed rig has four), in the ``world`` (the narrow one described above, or the
    wide one of :mod:`.robot_wide`, which draws its own arm poses and ignores ``arm``)."""

    width: int = 128
    height: int = 128
    cameras: CameraRig = "arc"
    arm: ArmPose = "home"
    views: int = NUM_VIEWS
    world: World = "narrow"


@dataclass(frozen=True)
class ObjectState:
    """One settled object: instance ``id`` (1..K, its value in masks/), ``name``, ``kind``, ``texture`` (primitives),
    ``center`` (3,) the centre of its axis-aligned box, ``aabb_min``/``aabb_max`` (3,) world metres, ``position``
    (3,) of its body origin, metres, and ``quaternion`` (4,) w x y z of its body."""

    id: int
    name: str
    kind: str
    texture: str | None
    center: tuple[float, float, float]
    aabb_min: tuple[float, float, float]
    aabb_max: tuple[float, float, float]
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]

    def to_json(self) -> dict:
        d = asdict(self)
        d["pose"] = {"position": d.pop("position"), "quaternion_wxyz": d.pop("quaternion")}
        return d


@dataclass
class CameraArc:
    """The camera placement as drawn: ``look_at`` (3,), ``elevation_deg``, ``distance`` (metres), ``azimuths_deg``
    (V,) for the arc; for the fixed rig ``names`` (V,) and no arc values, and, where they were drawn rather than
    :data:`RLBENCH_CAMERAS`'s, each camera's ``eyes`` (V, 3) and ``targets`` (V, 3), world metres."""

    rig: CameraRig
    look_at: tuple[float, float, float]
    fov_y_deg: float
    elevation_deg: float | None = None
    distance: float | None = None
    azimuths_deg: tuple[float, ...] = ()
    names: tuple[str, ...] = ()
    eyes: tuple[tuple[float, float, float], ...] = ()
    targets: tuple[tuple[float, float, float], ...] = ()

    def cameras(self, width: int, height: int) -> list[Camera]:
        """The views (float64, OpenCV convention), in trajectory order."""
        if self.rig == "arc":
            if self.elevation_deg is None or self.distance is None:
                raise ValueError("an arc of cameras needs its elevation_deg and distance")
            return [
                Camera.orbit(
                    self.look_at,
                    az,
                    float(self.elevation_deg),
                    float(self.distance),
                    fov_y_deg=self.fov_y_deg,
                    width=width,
                    height=height,
                    dtype=torch.float64,
                )
                for az in self.azimuths_deg
            ]
        eyes = self.eyes or tuple(RLBENCH_CAMERAS[n][0] for n in self.names)
        targets = self.targets or tuple(RLBENCH_CAMERAS[n][1] for n in self.names)
        return [
            Camera.look_at(eye, target, fov_y_deg=self.fov_y_deg, width=width, height=height, dtype=torch.float64)
            for eye, target in zip(eyes, targets, strict=True)
        ]

    def to_json(self) -> dict:
        out: dict = {"camera_rig": self.rig, "look_at": list(self.look_at), "fov_y_deg": self.fov_y_deg}
        if self.rig == "arc":
            out |= {
                "elevation_deg": self.elevation_deg,
                "elevations_deg": [self.elevation_deg] * len(self.azimuths_deg),
                "distance": self.distance,
                "distances": [self.distance] * len(self.azimuths_deg),
                "azimuths_deg": list(self.azimuths_deg),
                "front_view": len(self.azimuths_deg) // 2,
            }
        else:
            out["camera_names"] = list(self.names)
            if self.eyes:
                out["camera_eyes"] = [list(e) for e in self.eyes]
                out["camera_targets"] = [list(t) for t in self.targets]
        return out


def draw_cameras(rng: np.random.Generator, rig: CameraRig, views: int = NUM_VIEWS) -> CameraArc:
    """The scene's camera placement: ``views`` on an arc with one drawn elevation and distance, or the fixed rig."""
    if rig == "arc":
        return CameraArc(
            rig,
            LOOK_AT,
            FOV_Y_DEG,
            float(rng.uniform(*ELEVATION_RANGE)),
            float(rng.uniform(*DISTANCE_RANGE)),
            tuple(float(a) for a in np.linspace(AZIMUTH_RANGE[0], AZIMUTH_RANGE[1], views)),
        )
    return CameraArc(rig, (0.0, 0.0, 0.0), FOV_Y_DEG, names=tuple(RLBENCH_CAMERAS))


def camera_poses(cams: Sequence[Camera], mujoco) -> list[CameraPose]:
    """MuJoCo cameras for ``cams`` (the OpenGL frame of each camera: MuJoCo's camera axes)."""
    poses = []
    for i, cam in enumerate(cams):
        c2w = cam.to_opengl_c2w().to(torch.float64).numpy()
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(c2w[:3, :3]).reshape(-1))
        poses.append(CameraPose(f"view{i:03d}", float3(c2w[:3, 3]), float4(quat), cam.fov_y))
    return poses


# ------------------------------------------------------------------------------------------ objects
_EXTENTS: dict[str, tuple[float, float, float]] = {}


def _geom_boxes(comp: Composition, geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World axis-aligned boxes of visible geoms: (G, 3) min and max, from mesh vertices or exact primitive
    extents (box corners, cylinder rims, sphere), at the current ``comp.data`` kinematics."""
    m, d = comp.model, comp.data
    lo, hi = np.empty((len(geoms), 3)), np.empty((len(geoms), 3))
    for i, g in enumerate(geoms):
        R, p, size, gtype = d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g], m.geom_size[g], m.geom_type[g]
        if gtype == 7:  # mjGEOM_MESH
            adr, num = m.mesh_vertadr[m.geom_dataid[g]], m.mesh_vertnum[m.geom_dataid[g]]
            pts = m.mesh_vert[adr : adr + num].astype(np.float64) @ R.T + p
            lo[i], hi[i] = pts.min(0), pts.max(0)
            continue
        if gtype == 6:  # mjGEOM_BOX
            half = np.abs(R) @ size
        elif gtype == 5:  # mjGEOM_CYLINDER: rims of radius r about the axis R[:, 2], half height size[1]
            axis = R[:, 2]
            half = size[0] * np.sqrt(np.clip(1.0 - axis**2, 0.0, None)) + size[1] * np.abs(axis)
        elif gtype == 2:  # mjGEOM_SPHERE
            half = np.full(3, size[0])
        elif gtype == 3:  # mjGEOM_CAPSULE: a segment of half length size[1] along R[:, 2], radius size[0]
            half = size[0] + size[1] * np.abs(R[:, 2])
        elif gtype == 4:  # mjGEOM_ELLIPSOID: semi-axes size along R's columns
            half = np.sqrt(((R * size[None, :]) ** 2).sum(1))
        else:
            half = np.full(3, m.geom_rbound[g])
        lo[i], hi[i] = p - half, p + half
    return lo, hi


def object_box(comp: Composition, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(3,) min and max world corners of object ``k``'s (1-based) visible geoms."""
    geoms = np.flatnonzero((comp.geom_instance == k) & (comp.model.geom_group != 3))
    lo, hi = _geom_boxes(comp, geoms)
    return lo.min(0), hi.max(0)


def _extent(mujoco, assets: Path, kind: str) -> tuple[float, float, float]:
    """A robosuite object's (xy radius about its body origin, lowest z, highest z) metres, upright; cached."""
    if kind not in _EXTENTS:
        comp = compose(mujoco, assets, [ObjectSpec(kind, 0.0, 0.0, 0.0)], [], (64, 64))
        comp.data.qpos[comp.object_qpos[0] : comp.object_qpos[0] + 7] = (0, 0, 0, 1, 0, 0, 0)
        mujoco.mj_kinematics(comp.model, comp.data)
        geoms = np.flatnonzero(comp.geom_instance == 1)
        radius, zmin, zmax = 0.0, np.inf, -np.inf
        m, d = comp.model, comp.data
        for g in geoms:
            if m.geom_type[g] == 7:
                adr, num = m.mesh_vertadr[m.geom_dataid[g]], m.mesh_vertnum[m.geom_dataid[g]]
                pts = m.mesh_vert[adr : adr + num] @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
            else:
                lo, hi = _geom_boxes(comp, np.array([g]))
                pts = np.array([lo[0], hi[0], [lo[0, 0], hi[0, 1], 0], [hi[0, 0], lo[0, 1], 0]])
            radius = max(radius, float(np.hypot(pts[:, 0], pts[:, 1]).max()))
            zmin, zmax = min(zmin, float(pts[:, 2].min())), max(zmax, float(pts[:, 2].max()))
        _EXTENTS[kind] = (radius, zmin, zmax)
    return _EXTENTS[kind]


def _draw_object(rng: np.random.Generator, used: set[str]) -> ObjectSpec:
    """An object kind (a robosuite object not yet in the scene, or a textured primitive) at the origin."""
    free = [k for k in ASSET_OBJECTS if k not in used]
    if not free or rng.uniform() < PRIMITIVE_PROB:
        kind = PRIMITIVES[int(rng.integers(len(PRIMITIVES)))]
        texture = PRIMITIVE_TEXTURES[int(rng.integers(len(PRIMITIVE_TEXTURES)))]
        if kind == "box":
            half = float3(rng.uniform(*BOX_HALF, size=3))
        else:
            r = float(rng.uniform(*CYLINDER_RADIUS))
            half = (r, r, float(rng.uniform(*CYLINDER_HALF_HEIGHT)))
        return ObjectSpec(kind, 0.0, 0.0, 0.0, half, texture)
    return ObjectSpec(free[int(rng.integers(len(free)))], 0.0, 0.0, 0.0)


def _footprint(mujoco, assets: Path, obj: ObjectSpec) -> tuple[float, float]:
    """(xy radius, lowest z relative to the body origin) of ``obj`` at rest (upright; a capsule lying along its
    body's x), metres."""
    if obj.half_size is not None:
        hx, hy, hz = obj.half_size
        if obj.kind == "box":
            return math.hypot(hx, hy), -hz
        if obj.kind == "capsule":
            return hz + hx, -hx
        if obj.kind == "ellipsoid":
            return max(hx, hy), -hz
        return hx, -hz  # cylinder, sphere
    radius, zmin, _ = _extent(mujoco, assets, obj.kind)
    return radius, zmin


ObjectDraw = Callable[[np.random.Generator, set[str]], ObjectSpec]


def _draw_layout(
    mujoco,
    assets: Path,
    rng: np.random.Generator,
    table_half: float,
    draw: ObjectDraw = _draw_object,
    counts: tuple[int, int] = NUM_OBJECTS,
) -> tuple[list[ObjectSpec], list]:
    """``counts`` (2-5) objects drawn by ``draw`` (given the kinds already in the scene) at random positions and
    yaws on the table whose footprint discs do not overlap; returns them and their (radius, lowest z)."""
    while True:
        count = int(rng.integers(counts[0], counts[1] + 1))
        objects: list[ObjectSpec] = []
        feet: list[tuple[float, float]] = []
        used: set[str] = set()
        for _ in range(count):
            proto = draw(rng, used)
            radius, zmin = _footprint(mujoco, assets, proto)
            lim = table_half - TABLE_MARGIN - radius
            for _ in range(100):
                x, y = (float(v) for v in rng.uniform(-lim, lim, size=2))
                if all(math.hypot(x - o.x, y - o.y) >= radius + f[0] + GAP for o, f in zip(objects, feet, strict=True)):
                    objects.append(replace(proto, x=x, y=y, yaw=float(rng.uniform(-math.pi, math.pi))))
                    feet.append((radius, zmin))
                    used.add(proto.kind)
                    break
            else:
                break
        if len(objects) == count:
            return objects, feet


def _contacts(comp: Composition) -> tuple[bool, bool]:
    """(an object touches another object, an object or the table touches the arm) at the current state."""
    m, d = comp.model, comp.data
    inst, arm = comp.geom_instance, m.geom_conaffinity == 2
    obj_obj = obj_arm = False
    for c in d.contact[: d.ncon]:
        a, b = int(c.geom1), int(c.geom2)
        if c.dist > 0.0:
            continue
        if inst[a] and inst[b] and inst[a] != inst[b]:
            obj_obj = True
        if arm[a] or arm[b]:
            obj_arm = True
    return obj_obj, obj_arm


def _settle(mujoco, comp: Composition, arm: np.ndarray, fingers: tuple[float, ...] | None = (0.02, -0.02)) -> bool:
    """Step physics, holding the arm (and the gripper's joints at ``fingers``; None: its actuators drive them to
    their controls in ``comp.data.ctrl``), until every object (and a driven gripper) rests (speed below
    ``REST_SPEED``); False if they do not within ``SETTLE_MAX_SECONDS``."""
    m, d = comp.model, comp.data
    held = _arm_joint_ids(comp, fingers is not None)
    arm_dofs = np.concatenate([np.arange(m.jnt_dofadr[j], m.jnt_dofadr[j] + 1) for j in held])
    finger_dofs = [] if fingers is not None else [int(m.jnt_dofadr[j]) for j in _finger_joint_ids(comp)]
    steps_min = int(SETTLE_SECONDS / m.opt.timestep)
    for step in range(int(SETTLE_MAX_SECONDS / m.opt.timestep)):
        mujoco.mj_step(m, d)
        d.qpos[comp.arm_qpos] = arm
        if fingers is not None:
            d.qpos[comp.finger_qpos] = fingers
        d.qvel[arm_dofs] = 0.0
        if step >= steps_min and step % 25 == 0:
            speeds = [np.abs(d.qvel[m.body_dofadr[b] : m.body_dofadr[b] + 6]).max() for b in comp.object_bodies]
            speeds += [abs(float(d.qvel[i])) for i in finger_dofs]
            if max(speeds) < REST_SPEED:
                d.qvel[:] = 0.0
                mujoco.mj_forward(m, d)
                return True
    return False


def _arm_joint_ids(comp: Composition, fingers: bool = True) -> list[int]:
    """Joint ids of the arm (and, with ``fingers``, the gripper's joints)."""
    m = comp.model
    qpos_to_joint = {int(m.jnt_qposadr[j]): j for j in range(m.njnt)}
    return [qpos_to_joint[int(a)] for a in (*comp.arm_qpos, *(comp.finger_qpos if fingers else ()))]


def _finger_joint_ids(comp: Composition) -> list[int]:
    m = comp.model
    qpos_to_joint = {int(m.jnt_qposadr[j]): j for j in range(m.njnt)}
    return [qpos_to_joint[int(a)] for a in comp.finger_qpos]


def _draw_arm(rng: np.random.Generator, comp: Composition, pose: ArmPose) -> np.ndarray:
    """(7,) arm joint angles: home plus small offsets, exactly home ("still": the offsets are drawn and dropped, so
    the rest of the scene is the "home" scene's), or uniform within 90% of each joint's range."""
    lo, hi = comp.arm_range[:, 0], comp.arm_range[:, 1]
    if pose in ("home", "still"):
        offsets = rng.uniform(-ARM_OFFSET, ARM_OFFSET, size=7)
        q = np.asarray(PANDA_HOME) + (offsets if pose == "home" else 0.0)
    else:
        mid, half = (lo + hi) / 2, (hi - lo) / 2 * 0.9
        q = mid + rng.uniform(-1.0, 1.0, size=7) * half
    return np.clip(q, lo, hi)


def _boxes_clear(boxes: list[tuple[np.ndarray, np.ndarray]], table_half: np.ndarray, gap: float) -> bool:
    """Every box inside the table (less the margin), resting on it, and its x-y footprint ``gap`` from the others."""
    lim = table_half - TABLE_MARGIN + 0.03  # settled objects may roll or lean a little past their drop disc
    for i, (lo, hi) in enumerate(boxes):
        if (np.abs(lo[:2]) > lim).any() or (np.abs(hi[:2]) > lim).any() or lo[2] < -0.01 or lo[2] > 0.01:
            return False
        for lo2, hi2 in boxes[:i]:
            sep = np.maximum(lo2[:2] - hi[:2], lo[:2] - hi2[:2])
            if sep.max() < gap:
                return False
    return True


@dataclass
class SettledScene:
    """A composed, settled scene ready to render: its composition, objects and camera placement."""

    comp: Composition
    objects: list[ObjectState]
    specs: list[ObjectSpec]
    arm: np.ndarray
    arc: CameraArc
    config: RobotSceneConfig

    def objects_json(self, states: Sequence[ObjectState]) -> list[dict]:
        """scene.json's ``objects`` for ``states`` (the scene's, or those after an edit)."""
        return [o.to_json() for o in states]

    def to_json(self) -> dict:
        return {
            "family": "robot",
            "support_z": 0.0,
            "objects": self.objects_json(self.objects),
            "arm_joints_rad": [float(v) for v in self.arm],
            "robot_base": self.comp.robot_base.tolist(),
            "table_half_extent": [float(v) for v in self.comp.table_half],
            **self.arc.to_json(),
        }


def object_states(comp: Composition, specs: Sequence[ObjectSpec]) -> list[ObjectState]:
    """The objects' settled boxes and poses from ``comp.data``."""
    out = []
    for k, spec in enumerate(specs, start=1):
        lo, hi = object_box(comp, k)
        q = comp.data.qpos[comp.object_qpos[k - 1] : comp.object_qpos[k - 1] + 7]
        out.append(
            ObjectState(
                k,
                spec.name,
                spec.kind,
                spec.texture,
                float3((lo + hi) / 2),
                float3(lo),
                float3(hi),
                float3(q[:3]),
                float4(q[3:]),
            )
        )
    return out


def build_scene(rng: np.random.Generator, config: RobotSceneConfig, assets: Path | None = None) -> SettledScene:
    """Draw, compose and settle one scene (layouts that fail the checks are drawn again)."""
    mujoco = import_mujoco()
    assets = assets_dir(assets)
    arc = draw_cameras(rng, config.cameras, config.views)
    poses = camera_poses(arc.cameras(config.width, config.height), mujoco)
    table_half = None
    for _ in range(MAX_LAYOUT_TRIES):
        if table_half is None:  # the table's size, from the arena file
            table_half = compose(mujoco, assets, [], [], (8, 8)).table_half
        specs, feet = _draw_layout(mujoco, assets, rng, float(min(table_half)))
        comp = compose(mujoco, assets, specs, poses, (config.width, config.height))
        drop_objects(comp, specs, feet)
        arm = None
        for _ in range(20):
            cand = _draw_arm(rng, comp, config.arm)
            if arm_fits(mujoco, comp, cand):
                arm = cand
                break
        if arm is None or not settles_clear(mujoco, comp, arm):
            continue
        return SettledScene(comp, object_states(comp, specs), specs, arm, arc, config)
    raise RuntimeError(f"no valid robot layout in {MAX_LAYOUT_TRIES} tries")


def drop_objects(comp: Composition, specs: Sequence[ObjectSpec], feet: Sequence[tuple[float, float]]) -> None:
    """Put each object at its drop pose: its drawn x, y and yaw, its lowest point (``feet``' z) 2 mm above the
    table."""
    for adr, spec, (_, zmin) in zip(comp.object_qpos, specs, feet, strict=True):
        comp.data.qpos[adr : adr + 7] = (spec.x, spec.y, 0.002 - zmin, *yaw_quat(spec.yaw))


def arm_fits(mujoco, comp: Composition, q: np.ndarray) -> bool:
    """Set the arm to ``q`` (7,): True when it then touches neither the objects nor the table and keeps above the
    table top (:func:`_arm_clear_of_table`)."""
    comp.data.qpos[comp.arm_qpos] = q
    mujoco.mj_forward(comp.model, comp.data)
    return not _contacts(comp)[1] and _arm_clear_of_table(comp)


def settles_clear(
    mujoco, comp: Composition, arm: np.ndarray, fingers: tuple[float, ...] | None = (0.02, -0.02)
) -> bool:
    """Settle the objects (:func:`_settle`, holding the arm at ``arm``): True when they come to rest touching
    nothing, on the table, their footprints :data:`GAP` apart."""
    if not _settle(mujoco, comp, arm, fingers) or any(_contacts(comp)):
        return False
    boxes = [object_box(comp, k) for k in range(1, comp.object_bodies.size + 1)]
    return _boxes_clear(boxes, comp.table_half, GAP)


def _arm_clear_of_table(comp: Composition) -> bool:
    """The arm's and gripper's bodies stay above the table top where they are over it (random poses)."""
    d = comp.data
    arm_bodies = [b for b in range(comp.model.nbody) if comp.model.body(b).name.startswith("robot_link")]
    for b in arm_bodies:
        x, y, z = d.xpos[b]
        if abs(x) < comp.table_half[0] + 0.05 and abs(y) < comp.table_half[1] + 0.05 and z < 0.08:
            return False
    return True


# ------------------------------------------------------------------------------------------ scene files
def write_views(folder: Path, views: Views, cams: Sequence[Camera], meta: dict) -> None:
    """Write ``views`` as a scene folder's files into the existing folder ``folder``."""
    write_scene_files(folder, cams, views.rgb, views.depth, views.masks, meta)


# ------------------------------------------------------------------------------------------ edits
@dataclass(frozen=True)
class GroundTruthEdit:
    """The edits of one scene: object ``object_id`` (1-based instance id) moved by ``offset`` (3,) metres (z = 0),
    the same object lifted ``lift`` metres straight up from where it stood (None: it touches the arm or another
    object at every height of :data:`LIFT_HEIGHTS`, and the scene has no lift), and the same object removed."""

    object_id: int
    name: str
    offset: tuple[float, float, float]
    lift: float | None = None

    def to_json(self, kind: EditKind | None = None) -> dict:
        """``edits.json`` (``kind`` None): the object, the move's offset, each edit's folder (the lift's null where
        it has none) and ``lift_height`` metres (null likewise). An edit folder's ``scene.json`` (``kind``) records
        the object, the offset and the move's and removal's folders; the lift's folder also the lift's two keys."""
        out: dict = {
            "object": self.object_id,
            "name": self.name,
            "offset": list(self.offset),
            "move": "edits/move",
            "remove": "edits/remove",
        }
        if kind in (None, "lift"):
            out |= {"lift": None if self.lift is None else "edits/lift", "lift_height": self.lift}
        return out

    @property
    def kinds(self) -> tuple[EditKind, ...]:
        """The edits the scene has, in the order they are rendered."""
        return tuple(k for k in EDIT_KINDS if k != "lift" or self.lift is not None)


def draw_edit(rng: np.random.Generator, scene: SettledScene, mujoco) -> GroundTruthEdit | None:
    """An object and an offset of 0.10-0.20 m on the table that leave it clear of the others and the arm; None
    if no object of the scene can be moved so."""
    comp = scene.comp
    d = comp.data
    boxes = [object_box(comp, k) for k in range(1, len(scene.objects) + 1)]
    saved = d.qpos.copy()
    try:
        for k in (int(i) + 1 for i in rng.permutation(len(scene.objects))):
            for _ in range(60):
                dist, ang = rng.uniform(*MOVE_RANGE), rng.uniform(-math.pi, math.pi)
                off = np.array([dist * math.cos(ang), dist * math.sin(ang), 0.0])
                moved = [(lo + off, hi + off) if i == k - 1 else (lo, hi) for i, (lo, hi) in enumerate(boxes)]
                if not _boxes_clear(moved, comp.table_half, 2 * GAP):
                    continue
                d.qpos[comp.object_qpos[k - 1] : comp.object_qpos[k - 1] + 3] += off
                mujoco.mj_forward(comp.model, d)
                touching = any(_contacts(comp))
                d.qpos[:] = saved
                if not touching:
                    return GroundTruthEdit(k, scene.objects[k - 1].name, float3(off), lift_height(mujoco, scene, k))
        return None
    finally:
        d.qpos[:] = saved
        mujoco.mj_forward(comp.model, d)


def lift_height(mujoco, scene: SettledScene, k: int) -> float | None:
    """Metres object ``k`` (1-based) is lifted by, straight up from where it stood: the first of
    :data:`LIFT_HEIGHTS` (0.15 m down to 0.10 m) at which it touches neither the arm nor another object (the
    contact check of the move); None if it touches one at every height. Draws no random numbers, and leaves
    ``scene`` as it found it."""
    comp, d = scene.comp, scene.comp.data
    saved = d.qpos.copy()
    z = comp.object_qpos[k - 1] + 2
    try:
        for h in LIFT_HEIGHTS:
            d.qpos[z] = saved[z] + h
            mujoco.mj_forward(comp.model, d)
            if not any(_contacts(comp)):
                return h
        return None
    finally:
        d.qpos[:] = saved
        mujoco.mj_forward(comp.model, d)


def apply_edit(mujoco, scene: SettledScene, edit: GroundTruthEdit, kind: EditKind) -> list[ObjectState]:
    """Put ``scene`` in the edited state (no physics: the rest of the scene stays exactly as it was); returns
    the objects' states after it (the removed object is left out). A move or a lift is undone by restoring
    ``qpos``; the removal is the last edit rendered and is not undone."""
    comp = scene.comp
    k = edit.object_id
    if kind in ("move", "lift"):
        adr = comp.object_qpos[k - 1]
        if kind == "move":
            comp.data.qpos[adr : adr + 3] += np.asarray(edit.offset)
        elif edit.lift is not None:
            comp.data.qpos[adr + 2] += edit.lift
        else:
            raise ValueError(f"object {k} ({edit.name}) has no room to be lifted: the scene has no lift edit")
        mujoco.mj_forward(comp.model, comp.data)
        return object_states(comp, scene.specs)
    states = [o for o in object_states(comp, scene.specs) if o.id != k]
    geoms = np.flatnonzero(comp.geom_instance == k)
    comp.model.geom_group[geoms] = 3
    comp.model.geom_contype[geoms] = 0
    comp.model.geom_conaffinity[geoms] = 0
    mujoco.mj_forward(comp.model, comp.data)
    return states


# ------------------------------------------------------------------------------------------ scene folders
def write_robot_scene(
    folder: Path,
    rng: np.random.Generator,
    config: RobotSceneConfig,
    meta: dict,
    edits_rng: np.random.Generator | None,
    build: Callable[[np.random.Generator, RobotSceneConfig], SettledScene] = build_scene,
    generator: str = GENERATOR,
) -> dict:
    """Draw (``build``: the narrow world's :func:`build_scene`, or another world's), simulate and render one scene
    and write it as a complete scene folder at ``folder`` (built under a temporary name in the same parent and
    renamed at the end), its scene.json naming ``generator``. With ``edits_rng``, also its ground-truth edits
    under ``folder/edits/`` and ``folder/edits.json``. Returns seconds per stage."""
    import time

    from particlesplat.core.atomic import temp_sibling

    mujoco = import_mujoco()
    times = {}
    t0 = time.perf_counter()
    scene = build(rng, config)
    times["simulate"] = time.perf_counter() - t0
    cams = scene.arc.cameras(config.width, config.height)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(folder)
    tmp.mkdir()
    renderer = SceneRenderer(mujoco, scene.comp, config.width, config.height)
    try:
        t0 = time.perf_counter()
        views = renderer.render(scene.comp.camera_ids)
        times["render"] = time.perf_counter() - t0
        base = {"generator": generator, "format_version": FORMAT_VERSION, **meta, **scene.to_json()}
        write_views(tmp, views, cams, base)
        if edits_rng is not None:
            t0 = time.perf_counter()
            edit = draw_edit(edits_rng, scene, mujoco)
            if edit is not None:
                (tmp / "edits").mkdir()
                settled = scene.comp.data.qpos.copy()
                for kind in edit.kinds:
                    objects = apply_edit(mujoco, scene, edit, kind)
                    edited = renderer.render(scene.comp.camera_ids)
                    (tmp / "edits" / kind).mkdir()
                    info = {**base, "objects": scene.objects_json(objects), "edit": kind, **edit.to_json(kind)}
                    write_views(tmp / "edits" / kind, edited, cams, info)
                    scene.comp.data.qpos[:] = settled  # back to the original before the next edit
                    mujoco.mj_forward(scene.comp.model, scene.comp.data)
            (tmp / "edits.json").write_text(json.dumps(edit.to_json() if edit else {"object": None}, indent=1))
            times["edits"] = time.perf_counter() - t0
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        renderer.close()
    return times
