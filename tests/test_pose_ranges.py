"""A model whose layer follows a pose key warns when a scene's pose lies outside the range it was trained on; a
model that reads the robot's state by kinematics does not; a pose beyond the Panda's joint limits is refused."""

from __future__ import annotations

import json

import pytest

from particlesplat.core.errors import InputWarning
from particlesplat.core.panda_arm import ARM_STATE_DIMS, ARM_STATE_KEY
from particlesplat.data.pose_ranges import PoseRangeError
from particlesplat.data.scene_meta import scene_pose

JOINTS = [0.0, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8]
TRAINED = {
    "arm_joints_rad": {"min": [-0.5, 0.0, -0.5, -2.5, -0.5, 2.0, 0.5], "max": [0.5, 0.4, 0.5, -1.5, 0.5, 2.4, 1.1]}
}


def _scene(tmp_path, joints):
    (tmp_path / "scene.json").write_text(json.dumps({"family": "robot", "arm_joints_rad": joints}))
    return tmp_path


def test_a_pose_inside_its_range_is_read_quietly(tmp_path, recwarn):
    pose = scene_pose(_scene(tmp_path, JOINTS), "arm_joints_rad", 7, TRAINED)
    assert pose is not None and pose.tolist() == pytest.approx(JOINTS)
    assert not [w for w in recwarn if issubclass(w.category, InputWarning)]


def test_a_joint_outside_the_trained_range_is_named(tmp_path):
    outside = [*JOINTS[:3], -0.6, *JOINTS[4:]]  # joint 3: 0.9 rad above its trained maximum, inside its limits
    with pytest.warns(InputWarning, match=r"key 'arm_joints_rad'\[3\] is -0.6 rad, outside the \[-2.5, -1.5\]"):
        scene_pose(_scene(tmp_path, outside), "arm_joints_rad", 7, TRAINED)
    # the robot-state model reads the same scene by exact kinematics: no warning
    state = scene_pose(tmp_path, ARM_STATE_KEY, ARM_STATE_DIMS, {ARM_STATE_KEY: {"min": [0.0] * 21, "max": [0.0] * 21}})
    assert state is not None and state[3] == pytest.approx(-0.6)


def test_a_pose_beyond_the_joint_limits_is_refused(tmp_path):
    with pytest.raises(PoseRangeError, match=r"key 'arm_joints_rad'\[1\] is 2\.5 rad, beyond the joint's limits"):
        scene_pose(_scene(tmp_path, [0.0, 2.5, *JOINTS[2:]]), "arm_joints_rad", 7, TRAINED)
