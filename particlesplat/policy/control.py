"""Taking the Panda to a keypose: differential inverse kinematics on the joints, then joint torques.

A keypose is what a policy decides (:class:`Keypose`): where the gripper's grasp point goes (robosuite's ``eef``
body of the gripper, between the fingertips), how the hand is turned, and whether the gripper is then open or
closed. :class:`ArmController` takes the arm there the way a real arm is driven, through its joints:

- the grasp point's path from where it is to the keypose is a straight line (the hand's turn slerped along it),
  timed by a cosine profile at :data:`SPEED` metres and :data:`TURN_SPEED` radians a second;
- every :data:`CONTROL_EVERY` physics steps (50 Hz at MuJoCo's 2 ms step) the joint target moves to the path's
  next point by damped least squares on the grasp point's Jacobian (position and rotation), its null space pulled
  towards robosuite's home posture (:data:`PANDA_HOME`), within the joint limits;
- every physics step the arm's seven motors (robosuite's ``torq_j1..7``, within their torque ranges) apply
  computed torques: the joint-space mass matrix times a critically damped PD on the joint error, plus gravity
  and Coriolis forces (``qfrc_bias``);
- the gripper's two position actuators are then set open or closed (robosuite's Panda gripper: 0.04 m a finger,
  at most 20 N), and the arm holds its pose until the fingers stop.

World frame: robosuite's (metres, z = 0 the table top). Rotations are (3, 3) matrices whose columns are the
hand's axes in the world; quaternions are (w, x, y, z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from particlesplat.data.families.robot_compose import PANDA_HOME, Composition

CONTROL_EVERY = 10  # physics steps per joint-target update (2 ms steps: 50 Hz)
SPEED, TURN_SPEED = 0.35, 1.5  # m/s and rad/s along a path
MIN_MOVE_SECONDS = 0.2
SETTLE_SECONDS, MAX_SETTLE_SECONDS = 0.15, 1.5  # hold after a path: at least, at most
REACHED_POSITION, REACHED_SPEED = 0.004, 0.02  # metres, m/s: the grasp point counts as there
GRIPPER_SECONDS, MAX_GRIPPER_SECONDS = 0.25, 1.0  # the fingers move at least, at most this long
FINGER_REST_SPEED = 0.005  # m/s: the fingers have stopped
KP = 400.0  # 1/s^2: joint stiffness of the computed-torque law (natural frequency 20 rad/s)
KD = 2.0 * math.sqrt(KP)  # critically damped
IK_DAMPING = 1e-2  # damped least squares' damping (metres and radians alike)
NULL_GAIN = 0.1  # share of the distance to the home posture taken each update, in the Jacobian's null space
IK_ITERATIONS = 3  # damped least-squares iterations per joint-target update
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, 0.0
FINGER_TRAVEL = 0.04  # metres a Panda finger opens


@dataclass(frozen=True)
class Keypose:
    """The next end-effector pose and gripper state.

    Attributes:
        position: (3,) the grasp point's target, world metres.
        quaternion: (4,) w x y z of the hand's target frame (z: the approach axis; x: the fingers' closing axis).
        gripper: 1.0 open, 0.0 closed, after the arm has arrived.
    """

    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    gripper: float

    def as_array(self) -> np.ndarray:
        """(8,) float64: position, quaternion, gripper."""
        return np.array([*self.position, *self.quaternion, self.gripper], dtype=np.float64)

    @staticmethod
    def from_array(a: np.ndarray) -> Keypose:
        v = [float(x) for x in np.asarray(a, dtype=np.float64).reshape(8)]
        return Keypose((v[0], v[1], v[2]), (v[3], v[4], v[5], v[6]), v[7])


@dataclass
class MoveResult:
    """What one keypose's execution did: ``reached`` (the grasp point within :data:`REACHED_POSITION` of the
    target and slow), ``position_error`` (metres) and ``sim_seconds`` it took."""

    reached: bool
    position_error: float
    sim_seconds: float


def quat_to_matrix(q) -> np.ndarray:
    """(3, 3) rotation of the quaternion ``q`` (4,) w x y z (normalised here)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(np.asarray(q, dtype=np.float64))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """(4,) unit w x y z of the rotation ``R`` (3, 3), with w >= 0 (Shepperd's method: the largest of the four
    squared components first)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    cands = np.array([t, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(cands))
    if i == 0:
        w = math.sqrt(1.0 + t) / 2.0
        q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    else:
        a, b, c = i - 1, i % 3, (i + 1) % 3
        s = math.sqrt(max(1.0 + R[a, a] - R[b, b] - R[c, c], 1e-300)) * 2.0
        q = np.zeros(4)
        q[0] = (R[c, b] - R[b, c]) / s
        q[1 + a] = s / 4.0
        q[1 + b] = (R[b, a] + R[a, b]) / s
        q[1 + c] = (R[c, a] + R[a, c]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions (4,), the short way round; ``s`` in [0, 1]."""
    if q0 @ q1 < 0:
        q1 = -q1
    omega = math.acos(min(1.0, max(-1.0, float(q0 @ q1))))
    if omega < 1e-6:
        return q0.copy()
    q = (math.sin((1.0 - s) * omega) * q0 + math.sin(s * omega) * q1) / math.sin(omega)
    return q / np.linalg.norm(q)


def rotation_error(current: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(3,) the small rotation (axis times angle, world frame, radians) that turns ``current`` (3, 3) towards
    ``target`` (3, 3): half the sum of the cross products of their columns."""
    return 0.5 * np.cross(current.T, target.T).sum(0)


def hand_down(yaw: float) -> np.ndarray:
    """(3, 3) the hand pointing straight down (its z axis -z) with its closing axis (x) at ``yaw`` radians about
    +z from the world's x axis."""
    x = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return np.stack([x, np.cross(z, x), z], 1)


class ArmController:
    """Drives the arm and gripper of a composed workspace (:class:`Composition`, Panda gripper) by their
    actuators, stepping its physics. The controller's own MjData (``scratch``) holds the kinematics of the joint
    target; the simulation's state is ``comp.data``."""

    def __init__(self, mujoco, comp: Composition) -> None:
        m = comp.model
        self.mujoco, self.comp = mujoco, comp
        self.scratch = mujoco.MjData(m)
        self.eef = m.body("robot_gripper_eef").id
        joints = [m.joint(f"robot_joint{j}").id for j in range(1, 8)]
        self.arm_dofs = np.array([m.jnt_dofadr[j] for j in joints], dtype=np.int64)
        self.arm_motors = np.array([m.actuator(f"robot_torq_j{j}").id for j in range(1, 8)], dtype=np.int64)
        self.finger_dofs = np.array(
            [m.jnt_dofadr[j] for j in range(m.njnt) if m.joint(j).name.startswith("robot_gripper_")], dtype=np.int64
        )
        self.torque_range = m.actuator_ctrlrange[self.arm_motors].copy()
        self.low, self.high = comp.arm_range[:, 0], comp.arm_range[:, 1]
        self.home = np.asarray(PANDA_HOME, dtype=np.float64)
        self.mass = np.zeros((m.nv, m.nv))
        self.jacp, self.jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        self.target = comp.data.qpos[comp.arm_qpos].copy()
        self.opening = GRIPPER_OPEN

    # ------------------------------------------------------------------ state
    def eef_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The grasp point (3,) world metres and the hand's frame (3, 3), at the simulation's state."""
        d = self.comp.data
        return d.xpos[self.eef].copy(), d.xmat[self.eef].reshape(3, 3).copy()

    def eef_speed(self) -> float:
        """The grasp point's speed, m/s."""
        m, d = self.comp.model, self.comp.data
        self.mujoco.mj_jacBody(m, d, self.jacp, None, self.eef)
        return float(np.linalg.norm(self.jacp @ d.qvel))

    def finger_speed(self) -> float:
        return float(np.abs(self.comp.data.qvel[self.finger_dofs]).max())

    # ------------------------------------------------------------------ control laws
    def _ik_update(self, position: np.ndarray, rotation: np.ndarray) -> None:
        """Move the joint target towards the grasp point at ``position`` (3,) with the hand at ``rotation``."""
        m, s, mj = self.comp.model, self.scratch, self.mujoco
        q = self.target.copy()
        for _ in range(IK_ITERATIONS):
            s.qpos[self.comp.arm_qpos] = q
            mj.mj_kinematics(m, s)
            mj.mj_comPos(m, s)
            err = np.concatenate(
                [position - s.xpos[self.eef], rotation_error(s.xmat[self.eef].reshape(3, 3), rotation)]
            )
            mj.mj_jacBody(m, s, self.jacp, self.jacr, self.eef)
            J = np.concatenate([self.jacp[:, self.arm_dofs], self.jacr[:, self.arm_dofs]])
            pinv = J.T @ np.linalg.inv(J @ J.T + IK_DAMPING**2 * np.eye(6))
            null = (np.eye(7) - pinv @ J) @ (NULL_GAIN * (self.home - q))
            q = np.clip(q + pinv @ err + null, self.low, self.high)
        self.target = q

    def _apply_torques(self) -> None:
        """The arm motors' controls for this physics step: M (KP e - KD qdot) + bias, clipped to their ranges."""
        m, d, mj = self.comp.model, self.comp.data, self.mujoco
        q, qd = d.qpos[self.comp.arm_qpos], d.qvel[self.arm_dofs]
        mj.mj_fullM(m, d, self.mass)
        M = self.mass[np.ix_(self.arm_dofs, self.arm_dofs)]
        tau = M @ (KP * (self.target - q) - KD * qd) + d.qfrc_bias[self.arm_dofs]
        d.ctrl[self.arm_motors] = np.clip(tau, self.torque_range[:, 0], self.torque_range[:, 1])

    def set_gripper(self, opening: float) -> None:
        """Command the fingers: ``opening`` 1 open (0.04 m a finger), 0 closed (driven shut by the actuators)."""
        self.opening = float(opening)
        ctrl = [FINGER_TRAVEL * self.opening, -FINGER_TRAVEL * self.opening]
        self.comp.data.ctrl[self.comp.gripper_actuators] = ctrl

    def step(self, n: int = 1) -> None:
        """``n`` physics steps holding the current joint target and gripper command."""
        for _ in range(n):
            self._apply_torques()
            self.mujoco.mj_step(self.comp.model, self.comp.data)

    # ------------------------------------------------------------------ keyposes
    def move(self, position: np.ndarray, rotation: np.ndarray) -> MoveResult:
        """Take the grasp point along a straight line to ``position`` (3,) with the hand turning to ``rotation``
        (3, 3), then hold until it is there and slow (at most :data:`MAX_SETTLE_SECONDS`)."""
        m = self.comp.model
        dt = float(m.opt.timestep)
        p0, R0 = self.eef_pose()
        q0, q1 = matrix_to_quat(R0), matrix_to_quat(rotation)
        angle = 2.0 * math.acos(min(1.0, abs(float(q0 @ q1))))
        duration = max(float(np.linalg.norm(position - p0)) / SPEED, angle / TURN_SPEED, MIN_MOVE_SECONDS)
        steps = max(1, int(round(duration / dt)))
        start = float(self.comp.data.time)
        for i in range(0, steps, CONTROL_EVERY):
            s = min(1.0, (i + CONTROL_EVERY) / steps)
            s = 0.5 - 0.5 * math.cos(math.pi * s)
            self._ik_update(p0 + (position - p0) * s, quat_to_matrix(slerp(q0, q1, s)))
            self.step(CONTROL_EVERY)
        held = 0.0
        while True:
            self._ik_update(position, rotation)
            self.step(CONTROL_EVERY)
            held += CONTROL_EVERY * dt
            err = float(np.linalg.norm(self.eef_pose()[0] - position))
            done = err < REACHED_POSITION and self.eef_speed() < REACHED_SPEED
            if (done and held >= SETTLE_SECONDS) or held >= MAX_SETTLE_SECONDS:
                return MoveResult(done, err, float(self.comp.data.time) - start)

    def grip(self, opening: float) -> float:
        """Set the gripper and hold the arm while the fingers move (at least :data:`GRIPPER_SECONDS`, until they
        stop or :data:`MAX_GRIPPER_SECONDS`); returns the simulated seconds."""
        dt = float(self.comp.model.opt.timestep)
        self.set_gripper(opening)
        elapsed = 0.0
        while elapsed < MAX_GRIPPER_SECONDS:
            self.step(CONTROL_EVERY)
            elapsed += CONTROL_EVERY * dt
            if elapsed >= GRIPPER_SECONDS and self.finger_speed() < FINGER_REST_SPEED:
                break
        return elapsed

    def execute(self, keypose: Keypose) -> MoveResult:
        """Go to ``keypose``: the path to its pose with the gripper as it was, then its gripper state (the fingers
        move only when it differs from the current command)."""
        result = self.move(np.asarray(keypose.position), quat_to_matrix(keypose.quaternion))
        if abs(keypose.gripper - self.opening) > 1e-6:
            result.sim_seconds += self.grip(keypose.gripper)
        return result
