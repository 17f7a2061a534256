"""What a policy reads at a decision and what it outputs, as arrays: one :class:`Step` from a recorded episode
(:func:`episode_steps`) or from a live rollout (:func:`live_step`), turned into each input's numbers.

- the robot's state (every input has it): joint angles (7, radians), finger joints (2, metres), the gripper's
  command (1) and the grasp point's pose (3 metres, and the hand's rotation as its first two columns: a
  quaternion's sign is arbitrary, and a hand pointing down sits where it flips): :data:`ROBOT_DIMS` numbers;
- the true object state: one row per object and one for the goal pad (place): its box's centre and half extent
  (metres), its colour (RGB in [0, 1]; robosuite's printed objects: 0 with a flag), a goal flag and its shape
  (box, cylinder, sphere, capsule, other): :data:`OBJECT_DIMS` numbers, no role;
- the views: RGB in [0, 1] and depth / :data:`DEPTH_SCALE` as 4 channels a view.

A keypose is learned as :data:`ACTION_DIMS` numbers (EC-Diffuser's action): the position (metres), the
rotation's first two columns (a continuous 6-D rotation) and the gripper (1 open, 0 closed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .control import Keypose, matrix_to_quat, quat_to_matrix

ROBOT_DIMS = 19
SHAPES = ("box", "cylinder", "sphere", "capsule")  # one-hot; anything else is "other"
OBJECT_DIMS = 3 + 3 + 3 + 1 + 1 + len(SHAPES) + 1
ACTION_DIMS = 10
DEPTH_SCALE = 3.0  # metres: depth is read as depth / DEPTH_SCALE, clipped to [0, 1]


@dataclass
class Step:
    """What one decision sees (K objects, V views of H x W pixels).

    Attributes:
        joints: (7,); fingers: (2,); gripper: 1 open, 0 closed (the current command); eef: (7,) grasp point and
            hand quaternion.
        boxes: (K, 2, 3) the objects' box corners; colours: (K, 3) RGB (NaN: a printed object); shapes: (K,) kind.
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


def _object_row(box: np.ndarray, colour: np.ndarray, shape: str, goal: bool) -> np.ndarray:
    printed = bool(np.isnan(colour).any())
    onehot = [float(shape == s) for s in SHAPES] + [float(shape not in SHAPES)]
    centre, half = (box[0] + box[1]) / 2.0, (box[1] - box[0]) / 2.0
    rgb = np.zeros(3) if printed else colour
    return np.concatenate([centre, half, rgb, [float(printed), float(goal)], onehot])


def object_features(step: Step) -> np.ndarray:
    """(K + 1 with a goal, OBJECT_DIMS) float32: the objects' rows, then the goal pad's."""
    rows = [_object_row(b, c, s, False) for b, c, s in zip(step.boxes, step.colours, step.shapes, strict=True)]
    if not np.isnan(step.goal).any():
        r, top = step.goal_radius, float(step.goal[2])
        box = np.array([[step.goal[0] - r, step.goal[1] - r, 0.0], [step.goal[0] + r, step.goal[1] + r, top]])
        rows.append(_object_row(box, step.goal_colour, "cylinder", True))
    return np.stack(rows).astype(np.float32) if rows else np.zeros((0, OBJECT_DIMS), np.float32)


def image_features(step: Step) -> np.ndarray:
    """(V, 4, H, W) float32: RGB in [0, 1] and depth / DEPTH_SCALE clipped to [0, 1]."""
    if step.rgb is None or step.depth is None:
        raise ValueError("this step has no views")
    rgb = step.rgb.astype(np.float32).transpose(0, 3, 1, 2) / 255.0
    depth = np.clip(step.depth.astype(np.float32) / DEPTH_SCALE, 0.0, 1.0)[:, None]
    return np.concatenate([rgb, depth], 1)


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
    objects = [{"rgba": s.rgba, "texture": s.texture} for s in world.specs]
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
        obs.rgb,
        obs.depth,
        np.stack([c.K.double().numpy() for c in world.cameras]),
        np.stack([c.c2w.double().numpy() for c in world.cameras]),
        world.comp.robot_base,
    )
