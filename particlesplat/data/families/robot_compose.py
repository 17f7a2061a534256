"""Compose a robot-workspace MuJoCo model with ``mujoco.MjSpec`` from robosuite's asset files.

World frame: metres, +z up, z = 0 the table top, origin the table centre. The Panda stands behind the
table on the +y side facing -y, so a camera at azimuth 0 (on the -y side, see ``Camera.orbit_eye``)
looks at the robot across the table. Objects are free bodies ``object1`` ... ``objectK``; their geoms
collide with the table, each other and the arm (contact bits below), the arm collides with nothing
but objects and the table, so a layout or an arm pose that touches is found from ``data.contact``.
Collision-only geoms (robosuite's group 0 beside a visual twin) go to the hidden group 3.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .robot_assets import INSTALL, SimSetupError

AssetObject = Literal["can", "bread", "cereal", "milk", "lemon", "bottle"]
Primitive = Literal["box", "cylinder"]
ASSET_OBJECTS: tuple[AssetObject, ...] = ("can", "bread", "cereal", "milk", "lemon", "bottle")
PRIMITIVES: tuple[Primitive, ...] = ("box", "cylinder")
PRIMITIVE_TEXTURES = (
    "blue-wood",
    "red-wood",
    "green-wood",
    "light-wood",
    "dark-wood",
    "brass-ambra",
    "clay",
    "metal",
    "gray-felt",
    "wood-tiles",
    "pink-plaster",
    "yellow-plaster",
)
# The Panda's home joint angles (rad), as robosuite starts it, and its base behind the table's far edge.
PANDA_HOME = (0.0, math.pi / 16.0, 0.0, -math.pi / 2.0 - math.pi / 3.0, 0.0, math.pi - 0.2, math.pi / 4.0)
ROBOT_SETBACK = 0.16  # metres from the table's edge to the robot base (robosuite's offset for the Panda)
HIDDEN_GROUP = 3  # geoms in this group are never drawn
# MuJoCo's bindings ship no type stubs: its model and data are untyped (Any) where they enter this package
MjModel = Any  # mujoco.MjModel
MjData = Any  # mujoco.MjData
# contact bits: objects (type 3, affinity 1) touch table/objects (1) and the arm (affinity 2);
# the table is type 3 so the arm (type 0, affinity 2) touching it is seen; arm-arm pairs never collide.
OBJECT_CONTYPE, OBJECT_CONAFFINITY = 3, 1
TABLE_CONTYPE, TABLE_CONAFFINITY = 3, 1
ARM_CONTYPE, ARM_CONAFFINITY = 0, 2
PRIMITIVE_DENSITY = 400.0  # kg/m^3
SHADOW_MAP = 1024  # texels; plenty for 128 px views, 6x cheaper on llvmpipe than MuJoCo's 4096
NEAR, FAR = 0.04, 10.0  # metres: the GL clip planes (the arena's walls are within 4 m of any camera)


@dataclass(frozen=True)
class ObjectSpec:
    """One object dropped on the table.

    Attributes:
        kind: one of ``ASSET_OBJECTS`` (robosuite's meshes and textures) or ``PRIMITIVES``.
        x, y: drop position of the body origin, metres; yaw: about +z, radians.
        half_size: primitives only: box (hx, hy, hz), cylinder (r, r, hz), metres.
        texture: primitives only: a robosuite texture name from ``PRIMITIVE_TEXTURES``.
    """

    kind: str
    x: float
    y: float
    yaw: float
    half_size: tuple[float, float, float] | None = None
    texture: str | None = None

    @property
    def name(self) -> str:
        return self.kind if self.texture is None else f"{self.kind} ({self.texture})"


@dataclass(frozen=True)
class CameraPose:
    """A MuJoCo camera: ``pos`` (3,) world metres, ``quat`` (4,) w x y z of the camera frame (x right, y up,
    looking down -z: the OpenGL convention), ``fovy`` vertical field of view in degrees."""

    name: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    fovy: float


@dataclass
class Composition:
    """A compiled robot workspace and the ids needed to pose, settle and label it.

    Attributes:
        model, data: MuJoCo model and data.
        object_bodies: (K,) body id of ``object{k}``; object_qpos: (K,) qpos address of its free joint.
        arm_qpos: (7,) qpos addresses of the arm joints; finger_qpos: (2,) of the gripper fingers.
        arm_range: (7, 2) joint limits, radians.
        table_half: (2,) half extents of the table top, metres.
        geom_instance: (ngeom,) instance id per geom: k for object k's geoms, 0 for the rest.
        camera_ids: (V,) MuJoCo camera ids of the scene's views, in order.
    """

    model: MjModel
    data: MjData
    object_bodies: np.ndarray
    object_qpos: np.ndarray
    arm_qpos: np.ndarray
    finger_qpos: np.ndarray
    arm_range: np.ndarray
    table_half: np.ndarray
    geom_instance: np.ndarray = field(repr=False)
    camera_ids: list[int] = field(default_factory=list)


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation by ``yaw`` radians about +z."""
    return (math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))


def _load(mujoco, path: Path):
    try:
        return mujoco.MjSpec.from_file(str(path))
    except Exception as e:  # noqa: BLE001 - MuJoCo reports parse errors as ValueError or its own types
        raise SimSetupError(
            f"{path}: MuJoCo cannot read it ({' '.join(str(e).split())}); reinstall: '{INSTALL}'"
        ) from e


def _hide_collision_twins(spec) -> None:
    """Group-0 geoms of a spec that also has group-1 visual geoms are collision shapes: hide them."""
    if any(g.group == 1 for g in spec.geoms):
        for g in spec.geoms:
            if g.group == 0:
                g.group = HIDDEN_GROUP


def compose(
    mujoco, assets: Path, objects: Sequence[ObjectSpec], cameras: Sequence[CameraPose], res: tuple[int, int]
) -> Composition:
    """Build and compile the workspace: arena, Panda (gripper, mount), ``objects`` as free bodies at their drop
    poses (z = 0.3 m, lifted to rest later) and ``cameras``; ``res`` (width, height) sizes the offscreen buffer.
    The arm is at ``PANDA_HOME``."""
    world = mujoco.MjSpec()
    world.modelname = "particlesplat_robot_workspace"
    world.stat.extent = 2.0  # fixes the clip planes below (MuJoCo scales them by the extent)
    world.visual.map.znear = NEAR / world.stat.extent
    world.visual.map.zfar = FAR / world.stat.extent
    world.visual.quality.shadowsize = SHADOW_MAP
    world.visual.global_.offwidth, world.visual.global_.offheight = int(res[0]), int(res[1])
    # no headlight shading: colours must not depend on the viewpoint beyond the materials' specular
    world.visual.headlight.ambient = (0.25, 0.25, 0.25)
    world.visual.headlight.diffuse = (0.0, 0.0, 0.0)
    world.visual.headlight.specular = (0.0, 0.0, 0.0)

    arena = _load(mujoco, assets / "arenas" / "table_arena.xml")
    table = arena.body("table")
    top = arena.site("table_top")
    top_z = float(table.pos[2] + top.pos[2])
    table_half = np.array(arena.geom("table_visual").size[:2], dtype=np.float64)
    for g in arena.geoms:
        if g.name == "table_collision":
            g.contype, g.conaffinity = TABLE_CONTYPE, TABLE_CONAFFINITY
    _hide_collision_twins(arena)
    for light in arena.lights:
        light.diffuse = [0.45, 0.45, 0.45]
    # robosuite's arena has the robot on -x; turn it by -90 degrees so the robot is on +y
    world.attach(
        arena, prefix="arena_", frame=world.worldbody.add_frame(pos=[0, 0, -top_z], quat=yaw_quat(-math.pi / 2))
    )

    robot = _load(mujoco, assets / "robots" / "panda" / "robot.xml")
    gripper = _load(mujoco, assets / "grippers" / "panda_gripper.xml")
    mount = _load(mujoco, assets / "bases" / "rethink_mount.xml")
    for spec in (robot, gripper, mount):
        for g in spec.geoms:
            if g.group == 0:
                g.group = HIDDEN_GROUP
            if g.contype or g.conaffinity:
                g.contype, g.conaffinity = ARM_CONTYPE, ARM_CONAFFINITY
        for s in spec.sites:
            s.group = HIDDEN_GROUP
    # the mount is drawn as its collision primitives: its 33k-triangle pedestal mesh (mostly under the table
    # top) would cost a fifth of every view's GL time on a software rasteriser
    for g in mount.geoms:
        g.contype = g.conaffinity = 0
        g.group = HIDDEN_GROUP if g.type == mujoco.mjtGeom.mjGEOM_MESH else 1
        g.rgba = [0.2, 0.2, 0.2, 1.0]
    robot.body("right_hand").add_frame().attach_body(gripper.body("right_gripper"), "gripper_", "")
    base = [0.0, float(table_half[1]) + ROBOT_SETBACK, 0.0]
    world.attach(robot, prefix="robot_", frame=world.worldbody.add_frame(pos=base, quat=yaw_quat(-math.pi / 2)))
    world.attach(mount, prefix="mount_", frame=world.worldbody.add_frame(pos=base, quat=yaw_quat(-math.pi / 2)))

    textures = assets / "textures"
    for k, obj in enumerate(objects, start=1):
        body = world.worldbody.add_body(name=f"object{k}", pos=[obj.x, obj.y, 0.3], quat=yaw_quat(obj.yaw))
        body.add_freejoint(name=f"object{k}_free")
        if obj.kind in ASSET_OBJECTS:
            child = _load(mujoco, assets / "objects" / f"{obj.kind}.xml")
            _hide_collision_twins(child)
            for g in child.geoms:
                if g.contype or g.conaffinity:
                    g.contype, g.conaffinity = OBJECT_CONTYPE, OBJECT_CONAFFINITY
            for s in child.sites:
                s.group = HIDDEN_GROUP
            body.add_frame().attach_body(child.worldbody.first_body(), f"object{k}_", "")
        elif obj.kind in PRIMITIVES and obj.half_size is not None and obj.texture in PRIMITIVE_TEXTURES:
            png = textures / f"{obj.texture}.png"
            if not png.is_file():
                raise SimSetupError(f"{png}: robosuite texture missing; reinstall: '{INSTALL}'")
            tex = world.add_texture(name=f"object{k}_tex", file=str(png), type=mujoco.mjtTexture.mjTEXTURE_2D)
            mat = world.add_material(name=f"object{k}_mat", texrepeat=[1, 1], texuniform=False, specular=0.2)
            mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
            hx, hy, hz = obj.half_size
            is_box = obj.kind == "box"
            body.add_geom(
                name=f"object{k}_geom",
                type=mujoco.mjtGeom.mjGEOM_BOX if is_box else mujoco.mjtGeom.mjGEOM_CYLINDER,
                size=[hx, hy, hz] if is_box else [hx, hz, 0.0],
                material=mat.name,
                density=PRIMITIVE_DENSITY,
                contype=OBJECT_CONTYPE,
                conaffinity=OBJECT_CONAFFINITY,
                condim=4,
                group=0,
            )
        else:
            raise ValueError(f"object {k}: kind {obj.kind!r} needs a known texture and half_size for a primitive")

    # a key light from above the front-left that casts shadows on the table; the arena keeps its own light
    world.worldbody.add_light(
        name="key",
        pos=[0.6, -0.8, 2.5],
        dir=[-0.25, 0.35, -1.0],
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        castshadow=1,
        diffuse=[0.4, 0.4, 0.4],
        specular=[0.2, 0.2, 0.2],
        ambient=[0.0, 0.0, 0.0],
    )
    for cam in cameras:
        world.worldbody.add_camera(name=cam.name, pos=list(cam.pos), quat=list(cam.quat), fovy=cam.fovy)

    model = world.compile()
    data = mujoco.MjData(model)
    object_bodies = np.array([model.body(f"object{k}").id for k in range(1, len(objects) + 1)], dtype=np.int64)
    object_qpos = np.array(
        [model.jnt_qposadr[model.joint(f"object{k}_free").id] for k in range(1, len(objects) + 1)], dtype=np.int64
    )
    arm_joints = [model.joint(f"robot_joint{j}").id for j in range(1, 8)]
    fingers = [model.joint(f"robot_gripper_finger_joint{j}").id for j in (1, 2)]
    geom_instance = np.zeros(model.ngeom, dtype=np.int64)
    root = model.body_rootid[model.geom_bodyid]
    for k, b in enumerate(object_bodies, start=1):
        geom_instance[root == b] = k
    comp = Composition(
        model=model,
        data=data,
        object_bodies=object_bodies,
        object_qpos=object_qpos,
        arm_qpos=model.jnt_qposadr[arm_joints].astype(np.int64),
        finger_qpos=model.jnt_qposadr[fingers].astype(np.int64),
        arm_range=model.jnt_range[arm_joints].astype(np.float64),
        table_half=table_half,
        geom_instance=geom_instance,
        camera_ids=[model.camera(cam.name).id for cam in cameras],
    )
    data.qpos[comp.arm_qpos] = PANDA_HOME
    data.qpos[comp.finger_qpos] = (0.02, -0.02)
    return comp
