"""The world a policy task runs in: the wide robot world's workspace (robosuite's frame, the Panda with its own
gripper, the wide world's randomised lights, surfaces and object colours), seen by two fixed RGB-D cameras.

Everything here is the robot family's own code (:mod:`particlesplat.data.families`): the composition from
robosuite's asset files (``compose``, with a task's goal as a :class:`Marker` pad), the wide world's draws of
lights, surfaces and objects (``robot_wide``), dropping and settling the objects (``robot``) and the renderer
(``robot_render``). This module adds what a task needs beyond a scene: the fixed camera rig, a layout kept within
the arm's reach, and readouts of the simulator's state (objects' poses and boxes, what touches the gripper).

World frame (robosuite's): metres, +z up, z = 0 the table top, origin the table centre, the robot base behind
the table at x = -0.56 facing +x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from particlesplat.core.camera import Camera
from particlesplat.data.families.robot import (
    CameraArc,
    _footprint,
    camera_poses,
    drop_objects,
    object_box,
    settles_clear,
)
from particlesplat.data.families.robot_assets import assets_dir, import_mujoco
from particlesplat.data.families.robot_compose import PANDA_HOME, Composition, Marker, ObjectSpec, WorldSetup, compose
from particlesplat.data.families.robot_grippers import GRIPPERS
from particlesplat.data.families.robot_render import SceneRenderer, Views
from particlesplat.data.families.robot_wide import (
    FOV_Y_DEG,
    FRONT_AZIMUTH,
    HELDOUT_HUES,
    LOOK_AT,
    TRAIN,
    Ranges,
    draw_lights,
    draw_surface,
)

from .options import SPLITS

RESOLUTION = 128  # pixels, both cameras
# The rig: the two views the shipped robot model encodes by default (frames 4 and 16 of the wide world's arc of
# 21, 12 degrees apart about the front: 72 degrees either side of it), at the middle of the wide world's training
# elevations (20-50 degrees) and distances (0.8-1.2 m), looking at its look-at point.
RIG_AZIMUTHS = (FRONT_AZIMUTH - 72.0, FRONT_AZIMUTH + 72.0)  # degrees (Camera.orbit's)
RIG_ELEVATION, RIG_DISTANCE = 35.0, 1.0  # degrees, metres
CAMERA_NAMES = ("left", "right")
# Where objects and goals are put: within the arm's reach from straight above (the base stands at x = -0.56)
WORKSPACE_X, WORKSPACE_Y = (-0.22, 0.14), (-0.24, 0.24)  # metres, of a footprint's centre
CLEARANCE = 0.03  # metres between footprints (room for the open fingers beside an object)
MAX_PLACEMENT_TRIES, MAX_WORLD_TRIES = 200, 50
ARM_JITTER = 0.05  # radians: the arm starts at robosuite's home plus this much per joint at most
HELDOUT_EXTRA_DISTRACTORS = 1  # the held-out split has one more distractor than the task draws


def rig_cameras(resolution: int = RESOLUTION) -> list[Camera]:
    """The two fixed cameras (OpenCV convention, float64), left then right."""
    return rig_arc().cameras(resolution, resolution)


def rig_arc() -> CameraArc:
    """The rig as the robot family describes camera placements (an arc of two views)."""
    return CameraArc("arc", LOOK_AT, FOV_Y_DEG, RIG_ELEVATION, RIG_DISTANCE, RIG_AZIMUTHS)


def split_ranges(split: str) -> Ranges:
    """What a split's objects draw from: the wide world's training ranges; the held-out split takes its colours
    from the wide world's held-out hue bands (yellow, cyan and magenta, never in training)."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    return TRAIN if split == "train" else replace(TRAIN, hues=HELDOUT_HUES)


@dataclass
class TaskWorld:
    """A composed, settled task workspace.

    Attributes:
        comp: the MuJoCo composition (its ``data`` is the simulation's state).
        specs: (K,) the objects as drawn (object k + 1 in MuJoCo and in masks).
        roles: (K,) each object's role in the task ("target", "base", "distractor").
        goal: (3,) the centre of the goal pad's top (world metres), or None.
        goal_radius: metres (0 without a goal).
        setup: the gripper, lights and surfaces.
        cameras: the rig's two cameras; camera_ids: their MuJoCo ids.
        split: "train" or "heldout".
        gripper_geoms: (ngeom,) bool, the geoms of the gripper (hand and fingers).
    """

    comp: Composition
    specs: list[ObjectSpec]
    roles: list[str]
    goal: np.ndarray | None
    goal_radius: float
    setup: WorldSetup
    cameras: list[Camera]
    split: str
    gripper_geoms: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, bool))

    def index(self, role: str) -> int:
        """The 0-based index of the first object with ``role``."""
        return self.roles.index(role)

    def box(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Object ``k``'s (0-based) axis-aligned box: (3,) min and (3,) max world corners, metres."""
        return object_box(self.comp, k + 1)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The objects' body positions (K, 3) metres and quaternions (K, 4) w x y z."""
        d = self.comp.data
        q = np.stack([d.qpos[a : a + 7] for a in self.comp.object_qpos]) if self.specs else np.zeros((0, 7))
        return q[:, :3].copy(), q[:, 3:].copy()

    def speeds(self) -> np.ndarray:
        """(K,) each object's largest linear or angular velocity component (m/s, rad/s)."""
        m, d = self.comp.model, self.comp.data
        return np.array(
            [np.abs(d.qvel[m.body_dofadr[b] : m.body_dofadr[b] + 6]).max() for b in self.comp.object_bodies]
        )

    def touching_gripper(self, k: int) -> bool:
        """Object ``k`` (0-based) is in contact with the gripper."""
        d, inst = self.comp.data, self.comp.geom_instance
        for c in d.contact[: d.ncon]:
            a, b = int(c.geom1), int(c.geom2)
            if c.dist <= 0.0 and (
                (inst[a] == k + 1 and self.gripper_geoms[b]) or (inst[b] == k + 1 and self.gripper_geoms[a])
            ):
                return True
        return False

    def arm_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The arm's joint angles (7,) radians and the gripper's finger joints (2,) metres."""
        d = self.comp.data
        return d.qpos[self.comp.arm_qpos].copy(), d.qpos[self.comp.finger_qpos].copy()


def place_discs(
    rng: np.random.Generator, radii: Sequence[float], apart: Sequence[Sequence[float]] | None = None
) -> np.ndarray | None:
    """Centres (N, 2) of discs of ``radii`` (metres) within :data:`WORKSPACE_X` x :data:`WORKSPACE_Y`, each at
    least the sum of two radii plus :data:`CLEARANCE` from the others (plus ``apart[i][j]`` more, when given),
    placed one after another by rejection; None when a disc finds no room in :data:`MAX_PLACEMENT_TRIES`."""
    centres: list[np.ndarray] = []
    for i, r in enumerate(radii):
        for _ in range(MAX_PLACEMENT_TRIES):
            c = np.array([rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Y)])
            ok = all(
                np.linalg.norm(c - cj) >= r + radii[j] + CLEARANCE + (apart[i][j] if apart is not None else 0.0)
                for j, cj in enumerate(centres)
            )
            if ok:
                centres.append(c)
                break
        else:
            return None
    return np.stack(centres) if centres else np.zeros((0, 2))


def draw_setup(rng: np.random.Generator) -> WorldSetup:
    """The look of a task world: the wide world's lights and training surfaces, the Panda's own gripper."""
    return WorldSetup(
        frame="robosuite",
        gripper="panda",
        lights=draw_lights(rng),
        table=draw_surface(rng, TRAIN),
        floor=draw_surface(rng, TRAIN),
        walls=draw_surface(rng, TRAIN),
    )


def footprints(mujoco, assets, specs: Sequence[ObjectSpec]) -> list[tuple[float, float]]:
    """Each object's (xy radius, lowest z below its body origin) at rest, metres (the robot family's)."""
    return [_footprint(mujoco, assets, s) for s in specs]


def _gripper_geoms(comp: Composition) -> np.ndarray:
    m = comp.model
    names = [m.body(int(b)).name for b in m.geom_bodyid]
    return np.array([n.startswith("robot_gripper_") for n in names], dtype=bool)


def build_world(
    rng: np.random.Generator,
    specs: Sequence[ObjectSpec],
    roles: Sequence[str],
    goal: np.ndarray | None,
    goal_marker: Marker | None,
    setup: WorldSetup,
    split: str,
    assets=None,
) -> TaskWorld | None:
    """Compose ``specs`` (placed: their x, y and yaw) with the goal's marker and the rig, drop and settle them
    with the arm at home (plus :data:`ARM_JITTER`) and the gripper open; None when they do not come to rest on
    the table clear of each other and the arm."""
    mujoco = import_mujoco()
    assets = assets_dir(assets)
    cams = rig_cameras()
    poses = camera_poses(cams, mujoco)
    comp = compose(
        mujoco, assets, list(specs), poses, (RESOLUTION, RESOLUTION), setup, [goal_marker] if goal_marker else []
    )
    m, d = comp.model, comp.data
    drop_objects(comp, specs, footprints(mujoco, assets, specs))
    ctrl = GRIPPERS[setup.gripper].controls(m.actuator_ctrlrange[comp.gripper_actuators], 1.0)
    d.ctrl[comp.gripper_actuators] = ctrl
    arm = np.clip(
        np.asarray(PANDA_HOME) + rng.uniform(-ARM_JITTER, ARM_JITTER, 7), comp.arm_range[:, 0], comp.arm_range[:, 1]
    )
    if not settles_clear(mujoco, comp, arm, fingers=None):
        return None
    return TaskWorld(
        comp,
        list(specs),
        list(roles),
        goal,
        0.0 if goal_marker is None else goal_marker.radius,
        setup,
        cams,
        split,
        _gripper_geoms(comp),
    )


class RigRenderer:
    """The rig's two RGB-D views of a task world (MuJoCo's headless GL; close it when done)."""

    def __init__(self, world: TaskWorld) -> None:
        self.world = world
        # the rig's cameras look down at the table inside the room's walls and never see the sky: skipping it
        # changes no pixel (tested) and took a particles decision from 0.285 to 0.272 s on llvmpipe
        self.renderer = SceneRenderer(import_mujoco(), world.comp, RESOLUTION, RESOLUTION, skybox=False)

    def render(self) -> Views:
        """rgb (2, H, W, 3) uint8, planar depth (2, H, W) float32 metres (0: nothing), masks (2, H, W) uint8
        (object k + 1, 0 elsewhere), at the simulation's current state."""
        return self.renderer.render(self.world.comp.camera_ids)

    def close(self) -> None:
        self.renderer.close()


def yaw_of(quaternion: np.ndarray) -> float:
    """The turn about +z (radians) of a body whose quaternion (w, x, y, z) turns it about z (mostly)."""
    w, x, y, z = (float(v) for v in quaternion)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
