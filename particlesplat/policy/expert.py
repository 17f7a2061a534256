"""The scripted expert: keyposes for picking a task's target and putting it where the task says, chosen from the
simulator's privileged state.

At each decision the expert reads the objects' poses and boxes, the gripper's contacts and the grasp point, and
returns the next :class:`~particlesplat.policy.control.Keypose` (six a clean episode):

1. above the target, gripper open: at the height that clears every other object (straight-down approach);
2. at the grasp point, then closed: the target's middle height (2-3.5 cm under its top, at least 1.4 cm above the
   table), the fingers closing across a box's narrower side (any side of a cylinder), the hand turned within a
   quarter turn of its home yaw so the wrist never winds past its limit;
3. straight up to the carrying height (clears every other object's top with the target hanging below);
4. over the place point at that height: the place point (the task's: the goal's centre, the base's top) less the
   target's measured offset from the grasp point, so a grasp that slipped still lands centred;
5. down until the target's bottom is :data:`RELEASE_GAP` above the place point, then open;
6. straight up by :data:`RETREAT`, gripper open.

Closed loop: if the fingers closed on nothing, or the target is not lifted with the hand, the expert goes back
to step 1 (at most :data:`MAX_RETRIES` times); after step 6 it returns None (the episode is over).
"""

from __future__ import annotations

import math

import numpy as np

from .control import GRIPPER_CLOSED, GRIPPER_OPEN, Keypose, hand_down, matrix_to_quat
from .tasks import Task
from .world import TaskWorld, yaw_of

APPROACH = 0.10  # metres above the grasp point, at least, before descending
CLEAR_MARGIN = 0.06  # metres over the tallest other object's top (of the hanging target's bottom)
MIN_CARRY = 0.18  # metres: the grasp point's lowest carrying height
GRASP_BELOW_TOP = 0.02  # metres: the grasp point is at least this far under the target's top
GRASP_DEPTH = 0.035  # metres: and at most this far (the fingers are ~5 cm long: the palm stays over the top)
GRASP_FLOOR = 0.014  # metres: and at least this far above the table (the fingertips reach ~5 mm below it)
RELEASE_GAP = 0.004  # metres: the target's bottom over the place point when the fingers open
RETREAT = 0.10  # metres up after releasing
HOME_YAW = math.pi / 2.0  # the closing axis at robosuite's home pose: along world y
LIFTED = 0.015  # metres: the target's bottom above the table that counts as lifted
EMPTY_FINGERS = 0.004  # metres: fingers closed this far (each) hold nothing
MAX_RETRIES = 2
PHASES = ("above", "grasp", "lift", "over", "place", "retreat", "done")


def grasp_yaw(world: TaskWorld, k: int) -> float:
    """The closing axis' yaw (radians) for object ``k``: across a box's narrower horizontal side, else the home
    yaw; within a quarter turn of :data:`HOME_YAW` (a box's grasp is the same turned half a turn)."""
    spec = world.specs[k]
    yaw = HOME_YAW
    if spec.kind == "box" and spec.half_size is not None:
        _, quats = world.poses()
        hx, hy, _ = spec.half_size
        yaw = yaw_of(quats[k]) + (0.0 if hx <= hy else math.pi / 2.0)
    while yaw > HOME_YAW + math.pi / 2.0:
        yaw -= math.pi
    while yaw < HOME_YAW - math.pi / 2.0:
        yaw += math.pi
    return yaw


class Expert:
    """The scripted expert of one episode of ``task`` (it keeps the episode's phase; make one per episode)."""

    def __init__(self, task: Task) -> None:
        self.task = task
        self.phase = "above"
        self.retries = 0
        self.rotation = hand_down(HOME_YAW)
        self.grasp_point = np.zeros(3)

    def _keypose(self, position: np.ndarray, gripper: float) -> Keypose:
        p = [float(v) for v in position]
        q = [float(v) for v in matrix_to_quat(self.rotation)]
        return Keypose((p[0], p[1], p[2]), (q[0], q[1], q[2], q[3]), gripper)

    def _clear_height(self, world: TaskWorld, k: int, hang: float) -> float:
        """The grasp point's height that keeps ``hang`` metres under it clear of every object but ``k``."""
        tops = [world.box(j)[1][2] for j in range(len(world.specs)) if j != k]
        return max(MIN_CARRY, max(tops, default=0.0) + hang + CLEAR_MARGIN)

    def next_keypose(self, world: TaskWorld, eef: np.ndarray, fingers: np.ndarray) -> Keypose | None:
        """The next keypose, from the world's state, the grasp point ``eef`` (3,) and the finger joints (2,)
        metres; None when the episode is over."""
        k = world.index("target")
        lo, hi = world.box(k)
        if self.phase == "above":
            self.rotation = hand_down(grasp_yaw(world, k))
            centre = (lo + hi) / 2.0
            z = max(min(centre[2], hi[2] - GRASP_BELOW_TOP), hi[2] - GRASP_DEPTH, GRASP_FLOOR)
            self.grasp_point = np.array([centre[0], centre[1], z])
            self.phase = "grasp"
            height = max(z + APPROACH, self._clear_height(world, k, 0.0))
            return self._keypose(np.array([centre[0], centre[1], height]), GRIPPER_OPEN)
        if self.phase == "grasp":
            self.phase = "lift"
            return self._keypose(self.grasp_point, GRIPPER_CLOSED)
        hang = float(eef[2] - lo[2])
        if self.phase == "lift":
            if float(np.abs(fingers).max()) < EMPTY_FINGERS or not world.touching_gripper(k):
                return self._retry(world, eef)
            self.phase = "over"
            return self._keypose(np.array([eef[0], eef[1], self._clear_height(world, k, hang)]), GRIPPER_CLOSED)
        if self.phase in ("over", "place"):
            if lo[2] < LIFTED or not world.touching_gripper(k):
                return self._retry(world, eef)
            offset = (lo[:2] + hi[:2]) / 2.0 - eef[:2]
            point = self.task.place_point(world)
            xy = point[:2] - offset
            if self.phase == "over":
                self.phase = "place"
                return self._keypose(np.array([xy[0], xy[1], self._clear_height(world, k, hang)]), GRIPPER_CLOSED)
            self.phase = "retreat"
            return self._keypose(np.array([xy[0], xy[1], point[2] + hang + RELEASE_GAP]), GRIPPER_OPEN)
        if self.phase == "retreat":
            self.phase = "done"
            return self._keypose(np.array([eef[0], eef[1], eef[2] + RETREAT]), GRIPPER_OPEN)
        return None

    def _retry(self, world: TaskWorld, eef: np.ndarray) -> Keypose | None:
        """Back to the approach: open and rise (None when the retries are spent)."""
        if self.retries >= MAX_RETRIES:
            self.phase = "done"
            return None
        self.retries += 1
        self.phase = "above"
        k = world.index("target")
        return self._keypose(np.array([eef[0], eef[1], self._clear_height(world, k, 0.0)]), GRIPPER_OPEN)
