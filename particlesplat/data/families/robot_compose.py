"""Compose a robot-workspace MuJoCo model with ``mujoco.MjSpec`` from robosuite's asset files.

World frame: metres, +z up, z = 0 the table top, origin the table centre. By default (the "turned" frame of
the narrow world) the Panda stands behind the table on the +y side facing -y, so a camera at azimuth 0 (on the
-y side, see ``Camera.orbit_eye``) looks at the robot across the table; with a :class:`WorldSetup` in
robosuite's own frame it stands behind the table at -x facing +x, as robosuite places it, and the arena is not
turned. A :class:`WorldSetup` also picks the gripper (:mod:`.robot_grippers`), the lights and the table, floor
and wall textures and colours. Objects are free bodies ``object1`` ... ``objectK``; their geoms
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
from .robot_grippers import GRIPPERS

AssetObject = Literal["can", "bread", "cereal", "milk", "lemon", "bottle"]
Primitive = Literal["box", "cylinder"]
ASSET_OBJECTS: tuple[AssetObject, ...] = ("can", "bread", "cereal", "milk", "lemon", "bottle")
PRIMITIVES: tuple[Primitive, ...] = ("box", "cylinder")
# every robosuite object file and MuJoCo primitive a composition accepts (the narrow world draws the two above)
ALL_ASSET_OBJECTS = (*ASSET_OBJECTS, "square-nut", "round-nut")
ALL_PRIMITIVES = ("box", "cylinder", "sphere", "capsule", "ellipsoid")
Frame = Literal["turned", "robosuite"]
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
# robosuite stands the Panda on its Rethink mount with the base 0.912 m above the floor (the mount's 0.922 m
# less its 0.01 m top offset) and the table top at 0.8 m: in robosuite's frame the base is this far above the top
ROBOSUITE_BASE_HEIGHT = 0.912 - 0.8
ROBOSUITE_MOUNT_TOP = 0.01  # metres from the robot base up to the mount's frame (robosuite's top_offset)
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
        half_size: primitives only: box (hx, hy, hz), cylinder (r, r, hz), sphere (r, r, r), capsule lying along
            its body's x (r, r, half length of its axis), ellipsoid (a, b, c) semi-axes; metres.
        texture: primitives only: a robosuite texture name (a file ``textures/NAME.png``), or None for a plain
            colour (then ``rgba`` is needed).
        rgba: primitives only: the material's colour (it multiplies the texture), or None (white).
    """

    kind: str
    x: float
    y: float
    yaw: float
    half_size: tuple[float, float, float] | None = None
    texture: str | None = None
    rgba: tuple[float, float, float, float] | None = None

    @property
    def name(self) -> str:
        return self.kind if self.texture is None else f"{self.kind} ({self.texture})"


@dataclass(frozen=True)
class Surface:
    """How the table, the floor or the walls look: a robosuite ``texture`` name (None: the arena's own) and an
    ``rgba`` that multiplies it."""

    texture: str | None
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class Lights:
    """The key light (directional, casting shadows): ``key_pos`` (3,) and ``key_dir`` (3,) world, its
    ``key_diffuse`` grey level; ``arena_diffuse`` the arena's own light's grey level; ``ambient`` the headlight's
    ambient grey level (it has no diffuse or specular part, so colours do not follow the camera)."""

    key_pos: tuple[float, float, float]
    key_dir: tuple[float, float, float]
    key_diffuse: float
    arena_diffuse: float
    ambient: float


@dataclass(frozen=True)
class WorldSetup:
    """What a composition varies beyond its objects: the world ``frame`` (the robot at +y, "turned", or at -x as
    in robosuite), the ``gripper`` (a :data:`.robot_grippers.GRIPPERS` name), the lights and the surfaces."""

    frame: Frame = "turned"
    gripper: str = "panda"
    lights: Lights | None = None
    table: Surface | None = None
    floor: Surface | None = None
    walls: Surface | None = None


@dataclass(frozen=True)
class Marker:
    """A disc fixed on the table (a task's goal): centre ``x``, ``y`` and ``radius`` (metres), ``height`` (metres;
    it stands on z = 0 up to this height) and ``rgba``; with ``collides`` objects and the arm rest on it as on the
    table, else nothing touches it. It is part of the background (instance 0 in masks)."""

    name: str
    x: float
    y: float
    radius: float
    rgba: tuple[float, float, float, float]
    height: float = 0.002
    collides: bool = False


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
        arm_qpos: (7,) qpos addresses of the arm joints; finger_qpos: (J,) of the gripper's joints (the Panda
            gripper's two fingers in the narrow world); gripper_actuators: (A,) actuator ids of the gripper.
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
    gripper_actuators: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    finger_names: tuple[str, ...] = ()
    robot_base: np.ndarray = field(default_factory=lambda: np.eye(4))


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation by ``yaw`` radians about +z."""
    return (math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))


def _load(mujoco, path: Path):
    """The MjSpec of robosuite file ``path``. An asset whose name repeats an earlier one's is dropped first, as
    robosuite's own merging of a gripper's assets does (robotiq_gripper_85.xml names two meshes alike)."""
    try:
        text = path.read_text()
        if "<asset>" in text and _repeated_asset_names(text):
            spec = mujoco.MjSpec.from_string(_drop_repeated_assets(text))
            spec.modelfiledir = str(path.parent) + "/"
            return spec
        return mujoco.MjSpec.from_file(str(path))
    except Exception as e:  # noqa: BLE001 - MuJoCo reports parse errors as ValueError or its own types
        raise SimSetupError(
            f"{path}: MuJoCo cannot read it ({' '.join(str(e).split())}); reinstall: '{INSTALL}'"
        ) from e


def _asset_elements(text: str):
    import xml.etree.ElementTree as ET

    root = ET.fromstring(text)
    return root, [(asset, el) for asset in root.iter("asset") for el in list(asset)]


def _repeated_asset_names(text: str) -> bool:
    names = [(el.tag, el.get("name")) for _, el in _asset_elements(text)[1] if el.get("name")]
    return len(names) != len(set(names))


def _drop_repeated_assets(text: str) -> str:
    import xml.etree.ElementTree as ET

    root, elements = _asset_elements(text)
    seen = set()
    for asset, el in elements:
        key = (el.tag, el.get("name"))
        if key[1] and key in seen:
            asset.remove(el)
        seen.add(key)
    return ET.tostring(root, encoding="unicode")


def _hide_collision_twins(spec) -> None:
    """Group-0 geoms of a spec that also has group-1 visual geoms are collision shapes: hide them."""
    if any(g.group == 1 for g in spec.geoms):
        for g in spec.geoms:
            if g.group == 0:
                g.group = HIDDEN_GROUP


def _texture(world, mujoco, textures: Path, name: str, tex_name: str, kind=None):
    """Add robosuite texture ``name`` (``textures/NAME.png``) to ``world`` as ``tex_name``."""
    png = textures / f"{name}.png"
    if not png.is_file():
        raise SimSetupError(f"{png}: robosuite texture missing; reinstall: '{INSTALL}'")
    return world.add_texture(name=tex_name, file=str(png), type=kind or mujoco.mjtTexture.mjTEXTURE_2D)


def _dress_arena(arena, mujoco, textures: Path, setup: WorldSetup) -> None:
    """Retexture and tint the arena's table, floor and walls as ``setup`` says (in the arena's own spec, before
    it is attached)."""
    for surface, material, texture in (
        (setup.table, "table_ceramic", "tex-ceramic"),
        (setup.floor, "floorplane", "texplane"),
        (setup.walls, "walls_mat", "tex-light-gray-plaster"),
    ):
        if surface is None:
            continue
        if surface.texture is not None:
            png = textures / f"{surface.texture}.png"
            if not png.is_file():
                raise SimSetupError(f"{png}: robosuite texture missing; reinstall: '{INSTALL}'")
            arena.texture(texture).file = str(png)
        arena.material(material).rgba = list(surface.rgba)


def _add_primitive(world, mujoco, textures: Path, body, k: int, obj: ObjectSpec) -> None:
    """Object ``k``'s primitive geom (and its material) on ``body``."""
    if obj.half_size is None or (obj.texture is None and obj.rgba is None):
        raise ValueError(f"object {k}: a primitive {obj.kind!r} needs half_size and a texture or an rgba")
    mat = world.add_material(name=f"object{k}_mat", texrepeat=[1, 1], texuniform=False, specular=0.2)
    if obj.texture is not None:
        tex = _texture(world, mujoco, textures, obj.texture, f"object{k}_tex")
        mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
    if obj.rgba is not None:
        mat.rgba = list(obj.rgba)
    hx, hy, hz = obj.half_size
    G = mujoco.mjtGeom
    kinds = {
        "box": (G.mjGEOM_BOX, [hx, hy, hz]),
        "cylinder": (G.mjGEOM_CYLINDER, [hx, hz, 0.0]),
        "sphere": (G.mjGEOM_SPHERE, [hx, 0.0, 0.0]),
        "capsule": (G.mjGEOM_CAPSULE, [hx, hz, 0.0]),
        "ellipsoid": (G.mjGEOM_ELLIPSOID, [hx, hy, hz]),
    }
    gtype, size = kinds[obj.kind]
    extra = {"quat": [math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0]} if obj.kind == "capsule" else {}  # lying along x
    body.add_geom(
        name=f"object{k}_geom",
        type=gtype,
        size=size,
        material=mat.name,
        density=PRIMITIVE_DENSITY,
        contype=OBJECT_CONTYPE,
        conaffinity=OBJECT_CONAFFINITY,
        condim=4,
        group=0,
        **extra,
    )


def compose(
    mujoco,
    assets: Path,
    objects: Sequence[ObjectSpec],
    cameras: Sequence[CameraPose],
    res: tuple[int, int],
    setup: WorldSetup | None = None,
    markers: Sequence[Marker] = (),
) -> Composition:
    """Build and compile the workspace: arena, Panda (gripper, mount), ``objects`` as free bodies at their drop
    poses (z = 0.3 m, lifted to rest later), ``markers`` (discs fixed on the table, instance 0 in masks) and
    ``cameras``; ``res`` (width, height) sizes the offscreen buffer.
    ``setup`` (default: the narrow world's: turned frame, Panda gripper, the arena's look) picks the frame, the
    gripper, the lights and the surfaces. The arm is at ``PANDA_HOME``."""
    setup = setup or WorldSetup()
    if setup.gripper not in GRIPPERS:
        raise ValueError(f"gripper {setup.gripper!r}: not one of {', '.join(GRIPPERS)}")
    world = mujoco.MjSpec()
    world.modelname = "particlesplat_robot_workspace"
    world.stat.extent = 2.0  # fixes the clip planes below (MuJoCo scales them by the extent)
    world.visual.map.znear = NEAR / world.stat.extent
    world.visual.map.zfar = FAR / world.stat.extent
    world.visual.quality.shadowsize = SHADOW_MAP
    world.visual.global_.offwidth, world.visual.global_.offheight = int(res[0]), int(res[1])
    # no headlight shading: colours must not depend on the viewpoint beyond the materials' specular
    ambient = 0.25 if setup.lights is None else setup.lights.ambient
    world.visual.headlight.ambient = (ambient, ambient, ambient)
    world.visual.headlight.diffuse = (0.0, 0.0, 0.0)
    world.visual.headlight.specular = (0.0, 0.0, 0.0)
    textures = assets / "textures"

    arena = _load(mujoco, assets / "arenas" / "table_arena.xml")
    table = arena.body("table")
    top = arena.site("table_top")
    top_z = float(table.pos[2] + top.pos[2])
    table_half = np.array(arena.geom("table_visual").size[:2], dtype=np.float64)
    for g in arena.geoms:
        if g.name == "table_collision":
            g.contype, g.conaffinity = TABLE_CONTYPE, TABLE_CONAFFINITY
    _hide_collision_twins(arena)
    arena_diffuse = 0.45 if setup.lights is None else setup.lights.arena_diffuse
    for light in arena.lights:
        light.diffuse = [arena_diffuse] * 3
    _dress_arena(arena, mujoco, textures, setup)
    turned = setup.frame == "turned"
    # robosuite's arena has the robot on -x; the turned frame turns it by -90 degrees so the robot is on +y
    arena_quat = yaw_quat(-math.pi / 2) if turned else yaw_quat(0.0)
    world.attach(arena, prefix="arena_", frame=world.worldbody.add_frame(pos=[0, 0, -top_z], quat=arena_quat))

    robot = _load(mujoco, assets / "robots" / "panda" / "robot.xml")
    gripper = _load(mujoco, assets / GRIPPERS[setup.gripper].file)
    mount = _load(mujoco, assets / "bases" / "rethink_mount.xml")
    for spec in (robot, gripper, mount):
        if spec is gripper:
            _hide_collision_twins(spec)  # some grippers draw their group-0 geoms (no visual twins)
        for g in spec.geoms:
            if g.group == 0 and spec is not gripper:
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
    robot.body("right_hand").add_frame().attach_body(gripper.worldbody.first_body(), "gripper_", "")
    if turned:
        base, base_yaw, mount_z = [0.0, float(table_half[1]) + ROBOT_SETBACK, 0.0], -math.pi / 2, 0.0
    else:  # as robosuite places it
        base, base_yaw = [-(float(table_half[0]) + ROBOT_SETBACK), 0.0, ROBOSUITE_BASE_HEIGHT], 0.0
        mount_z = ROBOSUITE_BASE_HEIGHT + ROBOSUITE_MOUNT_TOP
    mount_pos = [base[0], base[1], mount_z]
    world.attach(robot, prefix="robot_", frame=world.worldbody.add_frame(pos=base, quat=yaw_quat(base_yaw)))
    world.attach(mount, prefix="mount_", frame=world.worldbody.add_frame(pos=mount_pos, quat=yaw_quat(base_yaw)))

    for k, obj in enumerate(objects, start=1):
        body = world.worldbody.add_body(name=f"object{k}", pos=[obj.x, obj.y, 0.3], quat=yaw_quat(obj.yaw))
        body.add_freejoint(name=f"object{k}_free")
        if obj.kind in ALL_ASSET_OBJECTS:
            child = _load(mujoco, assets / "objects" / f"{obj.kind}.xml")
            _hide_collision_twins(child)
            for g in child.geoms:
                if g.contype or g.conaffinity:
                    g.contype, g.conaffinity = OBJECT_CONTYPE, OBJECT_CONAFFINITY
            for s in child.sites:
                s.group = HIDDEN_GROUP
            body.add_frame().attach_body(child.worldbody.first_body(), f"object{k}_", "")
        elif obj.kind in ALL_PRIMITIVES:
            _add_primitive(world, mujoco, textures, body, k, obj)
        else:
            raise ValueError(f"object {k}: unknown kind {obj.kind!r}")

    for marker in markers:
        world.worldbody.add_geom(
            name=f"marker_{marker.name}",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[marker.radius, marker.height / 2.0, 0.0],
            pos=[marker.x, marker.y, marker.height / 2.0],
            rgba=list(marker.rgba),
            contype=TABLE_CONTYPE if marker.collides else 0,
            conaffinity=TABLE_CONAFFINITY if marker.collides else 0,
            condim=4 if marker.collides else 3,
            group=1,
        )
    # a key light from above the front-left that casts shadows on the table; the arena keeps its own light
    lights = setup.lights
    key_diffuse = 0.4 if lights is None else lights.key_diffuse
    world.worldbody.add_light(
        name="key",
        pos=[0.6, -0.8, 2.5] if lights is None else list(lights.key_pos),
        dir=[-0.25, 0.35, -1.0] if lights is None else list(lights.key_dir),
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        castshadow=1,
        diffuse=[key_diffuse] * 3,
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
    fingers = [j for j in range(model.njnt) if model.joint(j).name.startswith("robot_gripper_")]
    finger_set = set(fingers)
    actuators = [
        a for a in range(model.nu) if model.actuator_trntype[a] == 0 and int(model.actuator_trnid[a, 0]) in finger_set
    ]
    geom_instance = np.zeros(model.ngeom, dtype=np.int64)
    root = model.body_rootid[model.geom_bodyid]
    for k, b in enumerate(object_bodies, start=1):
        geom_instance[root == b] = k
    robot_base = np.eye(4)
    robot_base[:3, 3] = base
    robot_base[:2, :2] = [[math.cos(base_yaw), -math.sin(base_yaw)], [math.sin(base_yaw), math.cos(base_yaw)]]
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
        gripper_actuators=np.array(actuators, dtype=np.int64),
        finger_names=tuple(model.joint(j).name.removeprefix("robot_gripper_") for j in fingers),
        robot_base=robot_base,
    )
    data.qpos[comp.arm_qpos] = PANDA_HOME
    if setup.gripper == "panda":
        data.qpos[comp.finger_qpos] = (0.02, -0.02)
    return comp
