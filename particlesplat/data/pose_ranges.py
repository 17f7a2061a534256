"""The robot inputs a model reads (a scene's pose: ``scene.json``'s ``arm_joints_rad``,
``model.background.static_pose``), checked against what the robot can do and what the model was trained on.

- **Joint limits** (:data:`POSE_LIMITS`): a pose beyond them is no pose of the robot; every reader refuses it in one
  line naming the scene.json, the key and the joint (a 100-rad training scene would shift the workspace layer).
- **The trained range**: a run records each input's per-joint minimum and maximum over its training scenes in its
  checkpoints (``input_ranges``); a scene outside it (by more than :data:`RANGE_MARGIN` of the range's width, at
  least :data:`RANGE_MARGIN_MIN`) renders what the model never saw (every joint +0.6 rad: 11.3 dB against 26.6 on
  the first robot demo scene) and gets a warning. A checkpoint written before ranges were recorded is given its
  generator's range (:func:`generator_range`: the robot family's home pose +- its offsets).
"""

from __future__ import annotations

import math

from particlesplat.core.errors import UserError, warn_input

# The Panda's joint limits (radians), as robosuite's panda/robot.xml declares them (joint1..joint7 ``range``)
PANDA_JOINT_LIMITS = (
    (-2.8973, 2.8973),
    (-1.7628, 1.7628),
    (-2.8973, 2.8973),
    (-3.0718, -0.0698),
    (-2.8973, 2.8973),
    (-0.0175, 3.7525),
    (-2.8973, 2.8973),
)
POSE_LIMITS: dict[str, tuple[tuple[float, float], ...]] = {"arm_joints_rad": PANDA_JOINT_LIMITS}
RANGE_MARGIN = 0.1  # of the trained range's width
RANGE_MARGIN_MIN = 0.02  # radians


class PoseRangeError(UserError):
    """A robot input beyond the robot's limits, or a checkpoint's ``input_ranges`` that cannot be read."""


def check_limits(pose: list[float], key: str, where: str) -> None:
    """PoseRangeError naming ``where`` (the scene.json), ``key`` and the joint when ``pose`` is beyond the joint
    limits of the robot ``key`` belongs to (keys without known limits pass)."""
    limits = POSE_LIMITS.get(key)
    if limits is None or len(limits) != len(pose):
        return
    for j, (v, (lo, hi)) in enumerate(zip(pose, limits, strict=True)):
        if not lo <= v <= hi:
            raise PoseRangeError(
                f"{where}: key {key!r}[{j}] is {v:.6g} rad, beyond the joint's limits [{lo:g}, {hi:g}]"
            )


def record_range(poses: list[list[float]]) -> dict[str, list[float]]:
    """{"min": per-joint minimum, "max": per-joint maximum} of the training scenes' poses (S lists of D numbers)."""
    columns = list(zip(*poses, strict=True))
    return {"min": [float(min(c)) for c in columns], "max": [float(max(c)) for c in columns]}


def check_ranges(value: object, where: str) -> dict[str, dict[str, list[float]]] | None:
    """A checkpoint's ``input_ranges`` (key -> {"min": [...], "max": [...]}, finite, min <= max), checked; None when
    absent. PoseRangeError names ``where`` and the key otherwise."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise PoseRangeError(f"{where}: input_ranges: expected a mapping, got {type(value).__name__}")
    out = {}
    for key, r in value.items():
        lo = r.get("min") if isinstance(r, dict) else None
        hi = r.get("max") if isinstance(r, dict) else None
        if not (isinstance(lo, list) and isinstance(hi, list) and len(lo) == len(hi) and 0 < len(lo) <= 64) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in [*lo, *hi]
        ):
            raise PoseRangeError(f"{where}: input_ranges.{str(key)[:40]}: expected min and max lists of finite numbers")
        if any(a > b for a, b in zip(lo, hi, strict=True)):
            raise PoseRangeError(f"{where}: input_ranges.{str(key)[:40]}: a min above its max")
        out[str(key)] = {"min": [float(v) for v in lo], "max": [float(v) for v in hi]}
    return out


def generator_range(key: str) -> dict[str, list[float]] | None:
    """The range the robot family's generator draws ``key`` from with its default ``--arm home`` (the home pose +-
    its offsets), for checkpoints that record none (the shipped robot model was trained on such scenes)."""
    if key != "arm_joints_rad":
        return None
    from particlesplat.data.families.robot import ARM_OFFSET
    from particlesplat.data.families.robot_compose import PANDA_HOME

    return {"min": [h - ARM_OFFSET for h in PANDA_HOME], "max": [h + ARM_OFFSET for h in PANDA_HOME]}


def warn_outside(pose: list[float], key: str, trained: dict[str, list[float]] | None, where: str) -> None:
    """Warn (naming ``where``, ``key`` and the joint furthest out) when ``pose`` lies outside the ``trained`` range."""
    if trained is None or len(trained["min"]) != len(pose):
        return
    worst, j_worst = 0.0, -1
    for j, (v, lo, hi) in enumerate(zip(pose, trained["min"], trained["max"], strict=True)):
        margin = max(RANGE_MARGIN * (hi - lo), RANGE_MARGIN_MIN)
        out = max(lo - margin - v, v - hi - margin, 0.0)
        if out > worst:
            worst, j_worst = out, j
    if j_worst >= 0:
        v, lo, hi = pose[j_worst], trained["min"][j_worst], trained["max"][j_worst]
        warn_input(
            f"{where}: key {key!r}[{j_worst}] is {v:.4g} rad, outside the [{lo:.4g}, {hi:.4g}] the model was trained "
            "on: the render may be wrong"
        )
