"""What a policy reads at a decision and what it outputs, as arrays: one :class:`Step` from a recorded episode
(:func:`episode_steps`) or from a live rollout (:func:`live_step`), turned into each input's numbers.

- the robot's state (every input has it): joint angles (7, radians), finger joints (2, metres), the gripper's
  command (1) and the grasp point's pose (3 metres, and the hand's rotation as its first two columns: a
  quaternion's sign is arbitrary, and a hand pointing down sits where it flips): :data:`ROBOT_DIMS` numbers;
- the true object state: one row per object and one for the goal pad (place): its box's centre and half extent
  (metres, axis-aligned in the world), its footprint's turn (a box's short over long horizontal side subtracted
  from 1, and cos and sin of twice its long side's yaw: the same for a box turned half a turn; zeros for other
  shapes), its colour (RGB in [0, 1]; robosuite's printed objects: 0 with a flag), a goal flag
  and its shape (box, cylinder, sphere, capsule, other): :data:`OBJECT_DIMS` numbers, no role;
- the views: RGB in [0, 1] and depth / :data:`DEPTH_SCALE` as 4 channels a view.

A keypose is learned as :data:`ACTION_DIMS` numbers (EC-Diffuser's action): the position (metres), the
rotation's first two columns (a continuous 6-D rotation) and the gripper (1 open, 0 closed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .control import Keypose, matrix_to_quat, quat_to_matrix

ROBOT_DIMS = 19
GRASP_POINT = slice(10, 13)  # the grasp point's position within the robot's state (metres)
SHAPES = ("box", "cylinder", "sphere", "capsule")  # one-hot; anything else is "other"
OBJECT_DIMS = 3 + 3 + 3 + 3 + 1 + 1 + len(SHAPES) + 1
OBJECT_COLOUR = slice(9, 12)  # an object row's RGB
ACTION_DIMS = 10
DEPTH_SCALE = 3.0  # metres: depth is read as depth / DEPTH_SCALE, clipped to [0, 1]
IMAGE_CELL = 32  # pixels: the images input has a token per IMAGE_CELL x IMAGE_CELL block of a view


@dataclass
class Step:
    """What one decision sees (K objects, V views of H x W pixels).

    Attributes:
        joints: (7,); fingers: (2,); gripper: 1 open, 0 closed (the current command); eef: (7,) grasp point and
            hand quaternion.
        boxes: (K, 2, 3) the objects' box corners; colours: (K, 3) RGB (NaN: a printed object); shapes: (K,) kind;
            quaternions: (K, 4) w x y z; half_sizes: (K, 3) a primitive's own half sides, metres (NaN: a mesh).
        goal: (3,) the centre of the goal pad's top (NaN: none); goal_colour: (3,); goal_radius: metres.
        rgb: (V, H, W, 3) uint8 or None; depth: (V, H, W) float32 metres or None.
        intrinsics: (V, 3, 3) pixels; c2w: (V, 4, 4) OpenCV camera to world; robot_base: (4, 4) base to world.
    """

    joints: np.ndarray
    fingers: np.ndarray
    gripper: float
    eef: np.ndarray
    boxes: np.ndarray
    colours: np.ndarray
    shapes: list[str]
    goal: np.ndarray
    goal_colour: np.ndarray
    goal_radius: float
    quaternions: np.ndarray | None = None
    half_sizes: np.ndarray | None = None
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None
    intrinsics: np.ndarray | None = None
    c2w: np.ndarray | None = None
    robot_base: np.ndarray | None = None


def robot_features(step: Step) -> np.ndarray:
    """(ROBOT_DIMS,) float32."""
    R = quat_to_matrix(step.eef[3:7])
    return np.concatenate([step.joints, step.fingers, [step.gripper], step.eef[:3], R[:, 0], R[:, 1]]).astype(
        np.float32
    )


def footprint_turn(shape: str, quaternion: np.ndarray | None, half_size: np.ndarray | None) -> np.ndarray:
    """(3,) a box's footprint: 1 - short / long horizontal half side, cos 2a and sin 2a, a its long side's yaw
    (radians); zeros for any other shape or an unknown size or pose."""
    if shape != "box" or quaternion is None or half_size is None or np.isnan(half_size).any():
        return np.zeros(3)
    w, x, y, z = (float(v) for v in quaternion)
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    hx, hy = float(half_size[0]), float(half_size[1])
    a = yaw + (0.0 if hx >= hy else np.pi / 2.0)
    return np.array([1.0 - min(hx, hy) / max(hx, hy, 1e-9), np.cos(2.0 * a), np.sin(2.0 * a)])


def _object_row(box: np.ndarray, footprint: np.ndarray, colour: np.ndarray, shape: str, goal: bool) -> np.ndarray:
    printed = bool(np.isnan(colour).any())
    onehot = [float(shape == s) for s in SHAPES] + [float(shape not in SHAPES)]
    centre, half = (box[0] + box[1]) / 2.0, (box[1] - box[0]) / 2.0
    rgb = np.zeros(3) if printed else colour
    return np.concatenate([centre, half, footprint, rgb, [float(printed), float(goal)], onehot])


def object_features(step: Step) -> np.ndarray:
    """(K + 1 with a goal, OBJECT_DIMS) float32: the objects' rows, then the goal pad's."""
    rows = []
    for k, (box, colour, shape) in enumerate(zip(step.boxes, step.colours, step.shapes, strict=True)):
        q = None if step.quaternions is None else step.quaternions[k]
        half = None if step.half_sizes is None else step.half_sizes[k]
        rows.append(_object_row(box, footprint_turn(shape, q, half), colour, shape, False))
    if not np.isnan(step.goal).any():
        r, top = step.goal_radius, float(step.goal[2])
        box = np.array([[step.goal[0] - r, step.goal[1] - r, 0.0], [step.goal[0] + r, step.goal[1] + r, top]])
        rows.append(_object_row(box, np.zeros(3), step.goal_colour, "cylinder", True))
    return np.stack(rows).astype(np.float32) if rows else np.zeros((0, OBJECT_DIMS), np.float32)


def image_features(step: Step) -> np.ndarray:
    """(V, 4, H, W) float32: RGB in [0, 1] and depth / DEPTH_SCALE clipped to [0, 1]."""
    if step.rgb is None or step.depth is None:
        raise ValueError("this step has no views")
    rgb = step.rgb.astype(np.float32).transpose(0, 3, 1, 2) / 255.0
    depth = np.clip(step.depth.astype(np.float32) / DEPTH_SCALE, 0.0, 1.0)[:, None]
    return np.concatenate([rgb, depth], 1)


def image_points(step: Step, cell: int = IMAGE_CELL) -> np.ndarray:
    """(V * (H / cell) * (W / cell), 3) float32: the mean world point (metres) of each ``cell`` x ``cell`` block of
    each view's pixels, from planar depth and the OpenCV cameras, in the order the image input's tokens take
    (view, then row-major cells); a block without finite positive depth takes its camera's centre."""
    if step.depth is None or step.intrinsics is None or step.c2w is None:
        raise ValueError("this step has no views")
    V, H, W = step.depth.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64) + 0.5
    out = []
    for i in range(V):
        K, c2w = np.asarray(step.intrinsics[i], np.float64), np.asarray(step.c2w[i], np.float64)
        z = step.depth[i].astype(np.float64)
        valid = np.isfinite(z) & (z > 0)
        z = np.where(valid, z, 0.0)
        cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
        world = cam @ c2w[:3, :3].T + c2w[:3, 3]
        blocks = (world * valid[..., None]).reshape(H // cell, cell, W // cell, cell, 3).sum((1, 3))
        count = valid.reshape(H // cell, cell, W // cell, cell).sum((1, 3))[..., None]
        mean = np.where(count > 0, blocks / np.maximum(count, 1), c2w[:3, 3])
        out.append(mean.reshape(-1, 3))
    return np.concatenate(out).astype(np.float32)


def keypose_target(keypose: np.ndarray) -> np.ndarray:
    """(ACTION_DIMS,) float32 of a keypose (8,): position, the rotation's first two columns, gripper."""
    R = quat_to_matrix(keypose[3:7])
    return np.concatenate([keypose[:3], R[:, 0], R[:, 1], [keypose[7]]]).astype(np.float32)


def keypose_from_action(action: np.ndarray) -> Keypose:
    """The keypose of a predicted action (ACTION_DIMS,): the 6-D rotation made orthonormal (Gram-Schmidt), the
    gripper open when its number is over one half."""
    a = np.asarray(action, dtype=np.float64)
    x = a[3:6] / max(float(np.linalg.norm(a[3:6])), 1e-9)
    y = a[6:9] - (a[6:9] @ x) * x
    y /= max(float(np.linalg.norm(y)), 1e-9)
    q = matrix_to_quat(np.stack([x, y, np.cross(x, y)], 1))
    return Keypose(
        (float(a[0]), float(a[1]), float(a[2])),
        (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        1.0 if a[9] > 0.5 else 0.0,
    )


def _half_sizes(objects: list[dict]) -> np.ndarray:
    return np.array([o.get("half_size") or [np.nan] * 3 for o in objects], np.float64).reshape(-1, 3)


def _colours(objects: list[dict]) -> np.ndarray:
    return np.array(
        [[np.nan] * 3 if o.get("rgba") is None or o.get("texture") else o["rgba"][:3] for o in objects], np.float64
    )


def episode_steps(episode) -> list[tuple[Step, np.ndarray]]:
    """Each decision of a recorded episode (:class:`.episodes.Episode`) as (its step, the keypose taken (8,))."""
    objects = episode.meta["objects"]
    colours = _colours(objects)
    shapes = [o["kind"] for o in objects]
    goal_colour = np.asarray(episode.meta.get("goal_rgba") or [np.nan] * 4, np.float64)[:3]
    out = []
    for t in range(episode.steps):
        step = Step(
            episode["joints"][t],
            episode["fingers"][t],
            float(episode["gripper"][t]),
            episode["eef"][t],
            episode["object_boxes"][t],
            colours,
            shapes,
            episode["goal"],
            goal_colour,
            float(episode.meta.get("goal_radius", 0.0)),
            episode["object_quaternions"][t],
            _half_sizes(objects),
            episode["rgb"][t],
            episode["depth"][t],
            episode["intrinsics"],
            episode["c2w"],
            np.asarray(episode.meta["robot_base"], np.float64),
        )
        out.append((step, episode["keypose"][t]))
    return out


def live_step(world, obs) -> Step:
    """The step a policy sees in a live rollout: ``obs`` (:class:`.rollout.Observation`) of ``world``."""
    objects = [
        {"rgba": s.rgba, "texture": s.texture, "half_size": None if s.half_size is None else list(s.half_size)}
        for s in world.specs
    ]
    goal = np.full(3, np.nan) if world.goal is None else np.asarray(world.goal, np.float64)
    goal_colour = np.full(3, np.nan)
    if world.goal is not None:
        m = world.comp.model
        goal_colour = np.asarray(m.geom_rgba[m.geom("marker_goal").id][:3], np.float64)
    return Step(
        obs.joints,
        obs.fingers,
        float(obs.gripper),
        obs.eef,
        obs.object_boxes,
        _colours(objects),
        [s.kind for s in world.specs],
        goal,
        goal_colour,
        float(world.goal_radius),
        obs.object_quaternions,
        _half_sizes(objects),
        obs.rgb,
        obs.depth,
        np.stack([c.K.double().numpy() for c in world.cameras]),
        np.stack([c.c2w.double().numpy() for c in world.cameras]),
        world.comp.robot_base,
    )
