"""The wide robot world (``--world wide``): the robot family randomised the way sim-to-real work randomises a
workspace, in robosuite's own world frame, with a held-out split drawn outside the training ranges.

World frame (robosuite's): metres, +z up, z = 0 the table top, origin the table centre, the robot base behind
the table at -x facing +x (``robot_base`` in scene.json). A scene draws, within its split's :class:`Ranges`:

- objects: robosuite objects and MuJoCo primitives of random sizes, primitives coloured by a hue from the
  split's hue bands (plain or with a robosuite texture tinted by the colour);
- the arm: at rest (home plus noise), or the gripper's grasp point placed by inverse kinematics over an object
  (as when reaching for it) or anywhere in the workspace, with the approach axis tilted from straight down,
  clear of the table and the objects; the gripper (one of the split's robosuite grippers) at a drawn opening,
  closed by its own actuators;
- lights (direction, intensities) and the table, floor and wall textures and tints;
- cameras: 21 on an arc about a jittered look-at point at one drawn distance and elevation, or the four
  RLBench-style cameras at drawn distances about their jittered targets.

Train, val and test draw from :data:`TRAIN`; the held-out split from :data:`HELDOUT`, whose colours, textures,
grippers, object shapes and camera distances and elevations are outside :data:`TRAIN`'s.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import numpy as np

from .robot import (
    CameraArc,
    RobotSceneConfig,
    SettledScene,
    _draw_layout,
    _extent,
    arm_fits,
    camera_poses,
    drop_objects,
    object_states,
    settles_clear,
)
from .robot_assets import assets_dir, import_mujoco
from .robot_compose import PANDA_HOME, Composition, Lights, ObjectSpec, Surface, WorldSetup, compose
from .robot_grippers import GRIPPERS

GENERATOR = "particlesplat.data.families.robot_wide"
Interval = tuple[float, float]

# robosuite textures that are not an object's own print (can, bread, cereal, lemon, soda)
HELDOUT_TEXTURES = ("cream-plaster", "dirt", "glass", "gray-woodgrain", "steel-scratched", "white-bricks")
TRAIN_TEXTURES = (
    "blue-wood",
    "brass-ambra",
    "ceramic",
    "clay",
    "dark-wood",
    "gray-felt",
    "gray-plaster",
    "green-wood",
    "light-gray-floor-tile",
    "light-gray-plaster",
    "light-wood",
    "metal",
    "pink-plaster",
    "red-wood",
    "steel-brushed",
    "white-plaster",
    "wood-tiles",
    "wood-varnished-panels",
    "yellow-plaster",
)
# held-out hue bands (degrees), 24 degrees each about yellow, cyan and magenta; training draws the rest
HELDOUT_HUES: tuple[Interval, ...] = ((48.0, 72.0), (168.0, 192.0), (288.0, 312.0))
TRAIN_HUES: tuple[Interval, ...] = ((0.0, 48.0), (72.0, 168.0), (192.0, 288.0), (312.0, 360.0))
SATURATION, VALUE = (0.45, 1.0), (0.35, 1.0)  # primitives' colours (HSV)
SURFACE_SATURATION, SURFACE_VALUE = (0.0, 0.45), (0.5, 1.0)  # tints of the table, floor and walls
ARENA_LOOK_PROB = 0.25  # a surface keeps the arena's own texture and colour

NUM_OBJECTS = (2, 5)
PRIMITIVE_PROB = 0.5  # an object is a primitive (else a robosuite object not yet in the scene)
TEXTURE_PROB = 0.5  # a primitive carries a tinted texture (else a plain colour)
UNSEEN_PROB = 0.5  # held-out: an object after the first is of an unseen shape (the first always is)
BOX_HALF = (0.015, 0.06)
CYLINDER_RADIUS, CYLINDER_HALF_HEIGHT = (0.015, 0.045), (0.02, 0.08)
SPHERE_RADIUS = (0.02, 0.045)
CAPSULE_RADIUS, CAPSULE_HALF_LENGTH = (0.015, 0.035), (0.02, 0.06)
ELLIPSOID_AXES, ELLIPSOID_HEIGHT = (0.025, 0.06), (0.015, 0.03)  # semi-axes a, b; c <= min(a, b)

# lights
KEY_ELEVATION, KEY_DIFFUSE = (35.0, 80.0), (0.25, 0.7)  # degrees above the horizon, grey level
ARENA_DIFFUSE, AMBIENT = (0.2, 0.6), (0.15, 0.35)

# the arm: at rest (home plus noise, as robosuite starts it), else where the gripper's grasp point goes
REST_PROB, REST_SPREAD = 0.15, 0.25  # probability, radians per joint
OVER_OBJECT_PROB = 0.6
OVER_OBJECT_JITTER, OVER_OBJECT_HEIGHT = 0.03, (0.03, 0.25)  # metres about the object, above its top
WORKSPACE = ((-0.35, 0.3), (-0.35, 0.35), (0.05, 0.55))  # x, y, z ranges elsewhere (metres)
TILT_OVER_OBJECT, TILT_ELSEWHERE = 25.0, 60.0  # degrees of the approach axis from straight down
SEED_SPREAD = 0.5  # radians about home of the inverse kinematics' starting joints
IK_ITERATIONS, IK_DAMPING, IK_STEP = 150, 0.05, 0.2  # iterations, damping (m), largest joint step (rad)
IK_POSITION_TOL, IK_ANGLE_TOL = 0.01, 0.05  # metres, radians
OPEN_PROB, CLOSED_PROB = 1 / 3, 1 / 3  # the gripper fully open, fully closed (else uniform in between)
MAX_ARM_TRIES, MAX_LAYOUT_TRIES = 30, 200

# cameras
NUM_VIEWS, ARC_SPAN, FOV_Y_DEG = 21, 120.0, 40.0  # views, degrees either side of the front, degrees
FRONT_AZIMUTH = 90.0  # Camera.orbit's azimuth of the +x side (facing the robot across the table)
LOOK_AT = (0.0, 0.0, 0.05)
# RLBench-style cameras in robosuite's frame: (direction from the target to the eye, target)
RLBENCH_RIG = {
    "left_shoulder": ((-0.65, 0.55, 0.55), (0.1, 0.0, 0.0)),
    "front": ((0.95, 0.0, 0.55), (0.0, 0.0, 0.05)),
    "right_shoulder": ((-0.65, -0.55, 0.55), (0.1, 0.0, 0.0)),
    "overhead": ((0.05, 0.0, 1.0), (0.0, 0.0, 0.0)),
}
RLBENCH_DIRECTION_JITTER, RLBENCH_TARGET_JITTER = 0.08, 0.03


@dataclass(frozen=True)
class Ranges:
    """What one split draws from. Intervals are unions: a value is drawn from one of them (weighted by length).

    Attributes:
        grippers: robosuite grippers (:data:`.robot_grippers.GRIPPERS` names).
        hues: hue bands (degrees) of the primitives' colours and the surfaces' tints.
        textures: robosuite textures of primitives and surfaces.
        primitives, asset_objects: the object shapes drawn; unseen: shapes the held-out split adds (the first
            object of each of its scenes is one), none in training.
        arc_distance (metres), arc_elevation (degrees): of the arc; look_at_offset: (min, max) metres of the
            look-at point's offset from :data:`LOOK_AT` (uniform direction, the z part halved); arc_turn: degrees
            the arc's middle turns from the front at most.
        rig_distance: metres from each RLBench-style camera to its target.
    """

    grippers: tuple[str, ...]
    hues: tuple[Interval, ...]
    textures: tuple[str, ...]
    primitives: tuple[str, ...]
    asset_objects: tuple[str, ...]
    unseen: tuple[str, ...]
    arc_distance: tuple[Interval, ...]
    arc_elevation: tuple[Interval, ...]
    look_at_offset: Interval
    arc_turn: float
    rig_distance: tuple[Interval, ...]


TRAIN = Ranges(
    grippers=("panda", "rethink", "robotiq85"),
    hues=TRAIN_HUES,
    textures=TRAIN_TEXTURES,
    primitives=("box", "cylinder", "sphere", "capsule"),
    asset_objects=("can", "bread", "cereal", "milk", "lemon", "bottle", "square-nut"),
    unseen=(),
    arc_distance=((0.8, 1.2),),
    arc_elevation=((20.0, 50.0),),
    look_at_offset=(0.0, 0.08),
    arc_turn=10.0,
    rig_distance=((0.8, 1.2),),
)
HELDOUT = Ranges(
    grippers=("robotiq140",),
    hues=HELDOUT_HUES,
    textures=HELDOUT_TEXTURES,
    primitives=TRAIN.primitives,
    asset_objects=TRAIN.asset_objects,
    unseen=("ellipsoid", "round-nut"),
    arc_distance=((0.62, 0.78), (1.22, 1.4)),
    arc_elevation=((10.0, 18.0), (52.0, 65.0)),
    look_at_offset=(0.08, 0.12),
    arc_turn=10.0,
    rig_distance=((0.62, 0.78), (1.22, 1.4)),
)
SPLIT_RANGES = {"train": TRAIN, "val": TRAIN, "test": TRAIN, "heldout": HELDOUT}


def uniform_union(rng: np.random.Generator, intervals: tuple[Interval, ...]) -> float:
    """A value uniform over the union of disjoint ``intervals``."""
    lengths = np.array([hi - lo for lo, hi in intervals])
    k = int(rng.choice(len(intervals), p=lengths / lengths.sum()))
    return float(rng.uniform(*intervals[k]))


def draw_colour(rng: np.random.Generator, hues: tuple[Interval, ...], sat: Interval, val: Interval) -> tuple:
    """(r, g, b, 1) of a hue from ``hues`` (degrees) and saturation and value from ``sat`` and ``val``."""
    h = uniform_union(rng, hues) / 360.0
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, float(rng.uniform(*sat)), float(rng.uniform(*val)))
    return (r, g, b, 1.0)


def _pick(rng: np.random.Generator, items) -> str:
    return items[int(rng.integers(len(items)))]


def draw_primitive(rng: np.random.Generator, kind: str, ranges: Ranges) -> ObjectSpec:
    """A primitive ``kind`` of random size, colour and (maybe) texture at the origin."""
    if kind == "box":
        half = tuple(float(v) for v in rng.uniform(*BOX_HALF, size=3))
    elif kind == "cylinder":
        r = float(rng.uniform(*CYLINDER_RADIUS))
        half = (r, r, float(rng.uniform(*CYLINDER_HALF_HEIGHT)))
    elif kind == "sphere":
        r = float(rng.uniform(*SPHERE_RADIUS))
        half = (r, r, r)
    elif kind == "capsule":
        r = float(rng.uniform(*CAPSULE_RADIUS))
        half = (r, r, float(rng.uniform(*CAPSULE_HALF_LENGTH)))
    elif kind == "ellipsoid":
        a, b = (float(v) for v in rng.uniform(*ELLIPSOID_AXES, size=2))
        half = (a, b, float(rng.uniform(ELLIPSOID_HEIGHT[0], min(ELLIPSOID_HEIGHT[1], a, b))))
    else:
        raise ValueError(f"unknown primitive {kind!r}")
    rgba = draw_colour(rng, ranges.hues, SATURATION, VALUE)
    texture = _pick(rng, ranges.textures) if rng.uniform() < TEXTURE_PROB else None
    return ObjectSpec(kind, 0.0, 0.0, 0.0, (half[0], half[1], half[2]), texture, rgba)


def object_drawer(ranges: Ranges):
    """The split's object draw for :func:`.robot._draw_layout`: given the kinds already in the scene, a new
    object at the origin (a held-out scene's first object, and half the others, of an unseen shape)."""

    def draw(rng: np.random.Generator, used: set[str]) -> ObjectSpec:
        if ranges.unseen and (not used or rng.uniform() < UNSEEN_PROB):
            kinds = [k for k in ranges.unseen if k not in used or k == "ellipsoid"]
        elif rng.uniform() < PRIMITIVE_PROB:
            kinds = list(ranges.primitives)
        else:
            kinds = [k for k in ranges.asset_objects if k not in used] or list(ranges.primitives)
        kind = _pick(rng, kinds)
        if kind in ("box", "cylinder", "sphere", "capsule", "ellipsoid"):
            return draw_primitive(rng, kind, ranges)
        return ObjectSpec(kind, 0.0, 0.0, 0.0)

    return draw


def draw_surface(rng: np.random.Generator, ranges: Ranges) -> Surface:
    """The arena's own look (probability :data:`ARENA_LOOK_PROB`, training only) or a tinted split texture."""
    if ranges is TRAIN and rng.uniform() < ARENA_LOOK_PROB:
        return Surface(None, (1.0, 1.0, 1.0, 1.0))
    texture = _pick(rng, ranges.textures)
    return Surface(texture, draw_colour(rng, ranges.hues, SURFACE_SATURATION, SURFACE_VALUE))


def draw_lights(rng: np.random.Generator) -> Lights:
    """A key light from a random direction above the table and random intensities."""
    az, el = math.radians(rng.uniform(0.0, 360.0)), math.radians(rng.uniform(*KEY_ELEVATION))
    towards = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    pos = 2.5 * towards
    return Lights(
        (float(pos[0]), float(pos[1]), float(pos[2])),
        (float(-towards[0]), float(-towards[1]), float(-towards[2])),
        float(rng.uniform(*KEY_DIFFUSE)),
        float(rng.uniform(*ARENA_DIFFUSE)),
        float(rng.uniform(*AMBIENT)),
    )


def _offset(rng: np.random.Generator, radius: Interval) -> np.ndarray:
    """A look-at offset: a uniform direction (its z part halved) at a distance uniform in ``radius``."""
    v = rng.normal(size=3)
    v /= np.linalg.norm(v)
    v *= rng.uniform(*radius)
    v[2] *= 0.5
    return v


def draw_wide_cameras(rng: np.random.Generator, rig: str, ranges: Ranges, views: int = NUM_VIEWS) -> CameraArc:
    """The scene's cameras: ``views`` on an arc facing the robot across the table (azimuths
    :data:`FRONT_AZIMUTH` +- :data:`ARC_SPAN`, turned by up to ``ranges.arc_turn``), or the RLBench-style rig."""
    if rig == "arc":
        look_at = np.asarray(LOOK_AT) + _offset(rng, ranges.look_at_offset)
        middle = FRONT_AZIMUTH + float(rng.uniform(-ranges.arc_turn, ranges.arc_turn))
        elevation = uniform_union(rng, ranges.arc_elevation)
        distance = uniform_union(rng, ranges.arc_distance)
        azimuths = np.linspace(middle - ARC_SPAN, middle + ARC_SPAN, views)
        return CameraArc(
            "arc",
            (float(look_at[0]), float(look_at[1]), float(look_at[2])),
            FOV_Y_DEG,
            elevation,
            distance,
            tuple(float(a) for a in azimuths),
        )
    eyes, targets = [], []
    for direction, target in RLBENCH_RIG.values():
        d = np.asarray(direction) / np.linalg.norm(direction) + rng.uniform(-1, 1, 3) * RLBENCH_DIRECTION_JITTER
        t = np.asarray(target) + rng.uniform(-1, 1, 3) * RLBENCH_TARGET_JITTER
        eye = t + d / np.linalg.norm(d) * uniform_union(rng, ranges.rig_distance)
        eyes.append((float(eye[0]), float(eye[1]), float(eye[2])))
        targets.append((float(t[0]), float(t[1]), float(t[2])))
    return CameraArc(
        "rlbench", (0.0, 0.0, 0.0), FOV_Y_DEG, names=tuple(RLBENCH_RIG), eyes=tuple(eyes), targets=tuple(targets)
    )


# ------------------------------------------------------------------------------------------ the arm
def _rotation(approach: np.ndarray, yaw: float) -> np.ndarray:
    """(3, 3) a hand frame whose z axis is ``approach`` (unit) and whose x axis is turned by ``yaw`` about it."""
    z = approach / np.linalg.norm(approach)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = ref - (ref @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([c * x + s * y, -s * x + c * y, z], 1)


def solve_ik(mujoco, comp: Composition, target: np.ndarray, rot: np.ndarray, q0: np.ndarray) -> np.ndarray | None:
    """(7,) arm joints that put the gripper's grasp point (its ``eef`` body) at ``target`` (3,) and the hand's
    frame at ``rot`` (3, 3), by damped least squares from ``q0`` within the joint limits; None if it does not
    converge to :data:`IK_POSITION_TOL` and :data:`IK_ANGLE_TOL`."""
    m, d = comp.model, comp.data
    eef, hand = m.body("robot_gripper_eef").id, m.body("robot_right_hand").id
    dofs = np.array([m.jnt_dofadr[m.joint(f"robot_joint{j}").id] for j in range(1, 8)])
    lo, hi = comp.arm_range[:, 0], comp.arm_range[:, 1]
    q = np.clip(q0, lo, hi)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for _ in range(IK_ITERATIONS):
        d.qpos[comp.arm_qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        err_p = target - d.xpos[eef]
        cur = d.xmat[hand].reshape(3, 3)
        err_r = 0.5 * sum(np.cross(cur[:, i], rot[:, i]) for i in range(3))
        if np.linalg.norm(err_p) < IK_POSITION_TOL and np.linalg.norm(err_r) < IK_ANGLE_TOL:
            return q
        mujoco.mj_jacBody(m, d, jacp, None, eef)
        mujoco.mj_jacBody(m, d, None, jacr, hand)
        J = np.concatenate([jacp[:, dofs], jacr[:, dofs]])
        e = np.concatenate([err_p, err_r])
        dq = J.T @ np.linalg.solve(J @ J.T + IK_DAMPING**2 * np.eye(6), e)
        step = np.abs(dq).max()
        if step > IK_STEP:
            dq *= IK_STEP / step
        q = np.clip(q + dq, lo, hi)
    return None


def _height(mujoco, assets, spec: ObjectSpec, zmin: float) -> float:
    """Metres from the table top to ``spec``'s top when it rests (its lowest point ``zmin`` below its origin)."""
    if spec.half_size is not None:
        return -2.0 * zmin
    _, lo, hi = _extent(mujoco, assets, spec.kind)
    return hi - lo


def draw_arm_target(
    rng: np.random.Generator, specs: list[ObjectSpec], heights: list[float]
) -> tuple[np.ndarray, np.ndarray]:
    """Where the grasp point goes (3,) and the hand's frame (3, 3): over an object or anywhere in the
    workspace, the approach axis tilted from straight down and turned about itself at random."""
    if rng.uniform() < OVER_OBJECT_PROB:
        k = int(rng.integers(len(specs)))
        xy = np.array([specs[k].x, specs[k].y]) + rng.uniform(-OVER_OBJECT_JITTER, OVER_OBJECT_JITTER, 2)
        target = np.array([xy[0], xy[1], heights[k] + rng.uniform(*OVER_OBJECT_HEIGHT)])
        tilt = TILT_OVER_OBJECT
    else:
        target = np.array([rng.uniform(*WORKSPACE[0]), rng.uniform(*WORKSPACE[1]), rng.uniform(*WORKSPACE[2])])
        tilt = TILT_ELSEWHERE
    t, a = math.radians(rng.uniform(0.0, tilt)), rng.uniform(-math.pi, math.pi)
    approach = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), -math.cos(t)])
    return target, _rotation(approach, float(rng.uniform(-math.pi, math.pi)))


def draw_opening(rng: np.random.Generator) -> float:
    """The gripper's opening in [0 (closed), 1 (open)]: fully open, fully closed, or uniform in between."""
    u = rng.uniform()
    if u < OPEN_PROB:
        return 1.0
    if u < OPEN_PROB + CLOSED_PROB:
        return 0.0
    return float(rng.uniform())


# ------------------------------------------------------------------------------------------ the scene
@dataclass
class WideScene(SettledScene):
    """A settled scene of the wide world: a :class:`.robot.SettledScene` plus its ``setup`` (gripper, lights,
    surfaces), the gripper's ``opening`` and the split's ``ranges`` name."""

    setup: WorldSetup = WorldSetup()
    opening: float = 1.0
    ranges_name: str = "train"

    def objects_json(self, states) -> list[dict]:
        """scene.json's ``objects``, each with its primitive ``size`` and ``rgba`` (None for robosuite objects)."""
        objects = []
        for state in states:
            spec = self.specs[state.id - 1]
            entry = state.to_json()
            entry["size"] = None if spec.half_size is None else list(spec.half_size)
            entry["rgba"] = None if spec.rgba is None else list(spec.rgba)
            objects.append(entry)
        return objects

    def to_json(self) -> dict:
        comp, setup = self.comp, self.setup
        objects = self.objects_json(self.objects)
        surfaces = {
            name: None if s is None else {"texture": s.texture, "rgba": list(s.rgba)}
            for name, s in (("table", setup.table), ("floor", setup.floor), ("walls", setup.walls))
        }
        lights = None if setup.lights is None else {k: v for k, v in vars(setup.lights).items()}
        return {
            "family": "robot",
            "world": "wide",
            "world_frame": "robosuite",
            "ranges": self.ranges_name,
            "support_z": 0.0,
            "objects": objects,
            "arm_joints_rad": [float(v) for v in self.arm],
            "gripper": setup.gripper,
            "gripper_opening": float(self.opening),
            "gripper_joints": {
                n: float(comp.data.qpos[a]) for n, a in zip(comp.finger_names, comp.finger_qpos, strict=True)
            },
            "robot_base": comp.robot_base.tolist(),
            "table_half_extent": [float(v) for v in comp.table_half],
            "lights": lights,
            "surfaces": surfaces,
            **self.arc.to_json(),
        }


def build_wide_scene(
    rng: np.random.Generator, config: RobotSceneConfig, heldout: bool = False, assets=None
) -> WideScene:
    """Draw, compose and settle one scene of the wide world from the training ranges or, with ``heldout``, the
    held-out ones (layouts that fail the checks are drawn again)."""
    mujoco = import_mujoco()
    assets = assets_dir(assets)
    ranges = HELDOUT if heldout else TRAIN
    arc = draw_wide_cameras(rng, config.cameras, ranges, config.views)
    poses = camera_poses(arc.cameras(config.width, config.height), mujoco)
    setup = WorldSetup(
        frame="robosuite",
        gripper=_pick(rng, ranges.grippers),
        lights=draw_lights(rng),
        table=draw_surface(rng, ranges),
        floor=draw_surface(rng, ranges),
        walls=draw_surface(rng, ranges),
    )
    gripper = GRIPPERS[setup.gripper]
    draw = object_drawer(ranges)
    table_half = compose(mujoco, assets, [], [], (8, 8), setup).table_half
    for _ in range(MAX_LAYOUT_TRIES):
        specs, feet = _draw_layout(mujoco, assets, rng, float(min(table_half)), draw, NUM_OBJECTS)
        comp = compose(mujoco, assets, specs, poses, (config.width, config.height), setup)
        m, d = comp.model, comp.data
        drop_objects(comp, specs, feet)
        heights = [_height(mujoco, assets, s, f[1]) for s, f in zip(specs, feet, strict=True)]
        opening = draw_opening(rng)
        d.ctrl[comp.gripper_actuators] = gripper.controls(m.actuator_ctrlrange[comp.gripper_actuators], opening)
        arm = None
        for _ in range(MAX_ARM_TRIES):
            if rng.uniform() < REST_PROB:  # robosuite's start: home with noise
                q: np.ndarray | None = np.asarray(PANDA_HOME) + rng.uniform(-REST_SPREAD, REST_SPREAD, 7)
            else:
                target, rot = draw_arm_target(rng, specs, heights)
                q0 = np.asarray(PANDA_HOME) + rng.uniform(-SEED_SPREAD, SEED_SPREAD, 7)
                q = solve_ik(mujoco, comp, target, rot, q0)
            if q is not None and arm_fits(mujoco, comp, q):
                arm = q
                break
        if arm is None or not settles_clear(mujoco, comp, arm, fingers=None):
            continue
        return WideScene(
            comp,
            object_states(comp, specs),
            specs,
            arm,
            arc,
            config,
            setup=setup,
            opening=opening,
            ranges_name="heldout" if heldout else "train",
        )
    raise RuntimeError(f"no valid wide robot layout in {MAX_LAYOUT_TRIES} tries")
