"""Where a Franka Panda arm stands: forward kinematics from its joint angles, and the room it takes.

What a robot knows about itself (``scene.json``'s ``arm_joints_rad``, ``gripper`` and ``robot_base``;
docs/dataset.md) is enough to say which 3D points belong to the arm: the arm is a chain of links whose frames
follow robosuite's Panda model (``robots/panda/robot.xml``: each link's offset and rotation from its parent,
then a turn about its own z by its joint angle), and a point belongs to it when it lies within a link's
radius of the segment between two consecutive link origins, or of the gripper's axis.

Pure numpy/torch; no simulator. ``tests/test_panda_arm.py`` checks the chain against MuJoCo's bodies.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

# (offset from the parent frame (metres), rotation from the parent frame as a (w, x, y, z) quaternion), link 1..7
# then the hand, as robots/panda/robot.xml gives them
_S = math.sqrt(0.5)
PANDA_CHAIN: tuple[tuple[tuple[float, float, float], tuple[float, float, float, float]], ...] = (
    ((0.0, 0.0, 0.333), (1.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (_S, -_S, 0.0, 0.0)),
    ((0.0, -0.316, 0.0), (_S, _S, 0.0, 0.0)),
    ((0.0825, 0.0, 0.0), (_S, _S, 0.0, 0.0)),
    ((-0.0825, 0.384, 0.0), (_S, -_S, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (_S, _S, 0.0, 0.0)),
    ((0.088, 0.0, 0.0), (_S, _S, 0.0, 0.0)),
)
HAND_OFFSET = (0.0, 0.0, 0.1065)
"""The hand (the gripper's mount) from link 7, metres: along link 7's z, where the gripper starts."""
HAND_QUAT = (0.924, 0.0, 0.0, -0.383)
"""The hand's rotation from link 7, (w, x, y, z; normalised when used): about -45° about z, as robot.xml writes it."""

GRIPPER_REACH = {"panda": 0.12, "rethink": 0.14, "robotiq85": 0.16, "robotiq140": 0.22}
"""How far each gripper reaches past the hand along its axis, metres (fingers included, open or closed)."""
DEFAULT_GRIPPER_REACH = 0.22
"""The reach assumed for a gripper the scene does not name, or one not in :data:`GRIPPER_REACH`: the longest."""

ARM_STATE_KEY = "robot_state"
"""The pose key (``model.background.static_pose``) under which a model reads a scene's robot state
(:func:`pack_arm_state`)."""
ARM_STATE_DIMS = 21
ROBOSUITE_BASE = ((1.0, 0.0, 0.0, -0.56), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.112))
"""The base pose (top 3 rows, metres) a scene that records none is given: robosuite's, behind the table at -x
facing +x."""
NARROW_WORLD_BASE = ((0.0, 1.0, 0.0, 0.0), (-1.0, 0.0, 0.0, 0.56), (0.0, 0.0, 1.0, 0.0))
"""The narrow robot world's base pose (its frame turned a quarter turn: behind the table at +y facing -y), for
its scenes written before they recorded ``robot_base``."""

ARM_RADIUS = 0.13
"""The room a link takes about the segment between its origin and the next one's, metres: the Panda's links are
about 0.12 m across, and their origins sit off their centres by up to 0.06 m."""
GRIPPER_RADIUS = {"panda": 0.06, "rethink": 0.06, "robotiq85": 0.09, "robotiq140": 0.11}
"""The room each gripper takes about its axis, metres (an open Robotiq 140 is about 0.2 m across its fingers)."""


def pack_arm_state(joints: list[float], base: list[list[float]] | None, gripper: str | None) -> list[float]:
    """A scene's robot state as :data:`ARM_STATE_DIMS` numbers: the joints (7, radians), the base-to-world
    transform's top 3 rows (12, metres; None: :data:`ROBOSUITE_BASE`), and the gripper's reach and radius (metres,
    :data:`GRIPPER_REACH`, :data:`GRIPPER_RADIUS`; an unknown gripper: the largest)."""
    if len(joints) != 7:
        raise ValueError(f"a Panda has 7 joint angles, got {len(joints)}")
    rows = [list(r) for r in (base[:3] if base is not None else ROBOSUITE_BASE)]
    name = (gripper or "").lower()
    reach = GRIPPER_REACH.get(name, DEFAULT_GRIPPER_REACH)
    radius = GRIPPER_RADIUS.get(name, max(GRIPPER_RADIUS.values()))
    return [float(v) for v in joints] + [float(v) for r in rows for v in r] + [reach, radius]


def _quat_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    n = math.sqrt(sum(v * v for v in q))
    w, x, y, z = (v / n for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def link_frames(joints: np.ndarray | list[float], base: np.ndarray | None = None) -> np.ndarray:
    """World frames of the Panda's base, links 1-7 and hand.

    joints: (7,) joint angles, radians, base to wrist; base: (4, 4) base-to-world (metres; None = identity).
    Returns (9, 4, 4): the base (link 0), links 1..7 and the hand, each a 4×4 link-to-world transform.
    """
    q = np.asarray(joints, dtype=np.float64).reshape(-1)
    if q.shape != (7,):
        raise ValueError(f"a Panda has 7 joint angles, got {q.shape[0]}")
    T = np.eye(4) if base is None else np.asarray(base, dtype=np.float64)
    frames = [T]
    for (pos, quat), angle in zip(PANDA_CHAIN, q, strict=True):
        step = np.eye(4)
        step[:3, :3] = _quat_matrix(quat) @ _rot_z(float(angle))
        step[:3, 3] = pos
        T = T @ step
        frames.append(T)
    hand = np.eye(4)
    hand[:3, :3] = _quat_matrix(HAND_QUAT)
    hand[:3, 3] = HAND_OFFSET
    frames.append(T @ hand)
    return np.stack(frames)


def arm_capsules(
    joints: np.ndarray | list[float],
    base: np.ndarray | None = None,
    gripper: str | None = None,
    reach: float | None = None,
    gripper_radius: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The room the arm takes, as capsules: segments (N, 2, 3) world metres, and radii (N,) metres.

    The links' segments join consecutive origins of :func:`link_frames`; the last runs from the hand along its z
    axis by the gripper's reach (``reach``, else :data:`GRIPPER_REACH` of ``gripper``, :data:`DEFAULT_GRIPPER_REACH`
    for an unknown name), with the gripper's radius (``gripper_radius``, else :data:`GRIPPER_RADIUS`, the largest
    for an unknown name).
    Returns (starts (N, 3), ends (N, 3), radii (N,)).
    """
    frames = link_frames(joints, base)
    origins = frames[:, :3, 3]
    hand = frames[-1]
    name = (gripper or "").lower()
    if reach is None:
        reach = GRIPPER_REACH.get(name, DEFAULT_GRIPPER_REACH)
    if gripper_radius is None:
        gripper_radius = GRIPPER_RADIUS.get(name, max(GRIPPER_RADIUS.values()))
    tip = hand[:3, 3] + reach * hand[:3, 2]
    starts = np.concatenate([origins[:-1], hand[None, :3, 3]])
    ends = np.concatenate([origins[1:], tip[None]])
    radii = np.full(len(starts), ARM_RADIUS)
    radii[-1] = gripper_radius
    return starts, ends, radii


def state_capsules(state) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`arm_capsules` of a packed state (:func:`pack_arm_state`, :data:`ARM_STATE_DIMS` numbers)."""
    s = np.asarray(state, dtype=np.float64).reshape(-1)
    if s.shape[0] != ARM_STATE_DIMS:
        raise ValueError(f"a packed arm state has {ARM_STATE_DIMS} numbers, got {s.shape[0]}")
    base = np.eye(4)
    base[:3] = s[7:19].reshape(3, 4)
    return arm_capsules(s[:7], base, reach=float(s[19]), gripper_radius=float(s[20]))


def arm_points(state) -> np.ndarray:
    """The points that outline the arm of a packed state (:func:`pack_arm_state`): the base, the origins of
    links 1-7, the hand and the gripper's tip (its reach along the hand's z axis). Returns (10, 3) world metres."""
    starts, ends, _ = state_capsules(state)
    return np.concatenate([starts, ends[-1:]])


def capsule_distance(points: Tensor, starts: Tensor, ends: Tensor, radii: Tensor) -> Tensor:
    """How far points lie outside a set of capsules, metres (negative inside).

    points: (..., 3); starts, ends: (N, 3) segment ends; radii: (N,). Returns (...): the least over the capsules of
    (distance to the segment − radius).
    """
    seg = ends - starts  # (N, 3)
    rel = points[..., None, :] - starts  # (..., N, 3)
    t = ((rel * seg).sum(-1) / (seg * seg).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
    gap = (rel - t[..., None] * seg).norm(dim=-1) - radii
    return gap.min(dim=-1).values


def in_arm(
    points: Tensor, joints: np.ndarray | list[float], base: np.ndarray | None = None, gripper: str | None = None
) -> Tensor:
    """points: (..., 3) world metres -> (...) bool: inside the room the arm takes (:func:`arm_capsules`)."""
    caps = arm_capsules(joints, base, gripper)
    starts, ends, radii = (torch.as_tensor(a, dtype=points.dtype, device=points.device) for a in caps)
    return capsule_distance(points, starts, ends, radii) < 0


__all__ = [
    "ARM_RADIUS",
    "ARM_STATE_DIMS",
    "ARM_STATE_KEY",
    "ROBOSUITE_BASE",
    "pack_arm_state",
    "DEFAULT_GRIPPER_REACH",
    "GRIPPER_RADIUS",
    "GRIPPER_REACH",
    "PANDA_CHAIN",
    "arm_capsules",
    "capsule_distance",
    "in_arm",
    "link_frames",
]
