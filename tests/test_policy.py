"""The policy tasks in the robot world, checked against the simulator: a target put on the goal (or the base) by
hand succeeds and one put beside it fails; the controller takes the grasp point where a keypose says; the
scripted expert solves each task on a few seeds; quaternions against MuJoCo's own conversion."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from particlesplat.data.families.robot_assets import INSTALL

if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None:
    pytest.skip(f"policy tasks need the sim extra: {INSTALL}", allow_module_level=True)


def _world(task: str, index: int = 0, split: str = "train"):
    from particlesplat.policy.tasks import TASKS, build_task_world, episode_rng

    return build_task_world(episode_rng(7, task, split, index), TASKS[task], split)


def _put(world, k: int, xy, bottom: float, steps: int = 250) -> None:
    """Put object ``k`` upright (its drawn yaw kept) with its lowest point at ``bottom``, at rest, and let physics
    settle it for ``steps`` steps (0.5 s) with the arm held where it is."""
    from particlesplat.data.families.robot_assets import import_mujoco
    from particlesplat.policy.control import ArmController

    mujoco = import_mujoco()
    comp = world.comp
    adr = comp.object_qpos[k]
    lo, _ = world.box(k)
    below = comp.data.qpos[adr + 2] - lo[2]  # body origin above its lowest point
    comp.data.qpos[adr : adr + 3] = (xy[0], xy[1], bottom + below + 0.001)
    comp.data.qvel[:] = 0.0
    mujoco.mj_forward(comp.model, comp.data)
    ArmController(mujoco, comp).step(steps)


def test_place_success_by_hand():
    from particlesplat.policy.tasks import placed

    world = _world("place")
    k = world.index("target")
    assert not placed(world)  # where it starts, MIN_TRAVEL away from the goal
    top = float(world.goal[2])
    _put(world, k, world.goal[:2] + [0.01, -0.01], top)
    assert placed(world)
    assert abs(world.box(k)[0][2] - top) < 0.003  # it rests on the pad
    _put(world, k, world.goal[:2] + [world.goal_radius + 0.04, 0.0], 0.0)  # on the table beside the pad
    assert not placed(world)
    _put(world, k, world.goal[:2], top + 0.05, steps=0)  # over the pad, held in the air
    assert not placed(world)


def test_stack_success_by_hand():
    from particlesplat.policy.tasks import stacked

    world = _world("stack")
    a, b = world.index("target"), world.index("base")
    assert not stacked(world)
    lo_b, hi_b = world.box(b)
    top = (lo_b[:2] + hi_b[:2]) / 2.0
    _put(world, a, top + [0.005, 0.0], float(hi_b[2]))
    assert stacked(world)
    lo_a, hi_a = world.box(a)
    assert abs(lo_a[2] - world.box(b)[1][2]) < 0.003  # it rests on the base's top face
    _put(world, a, top + [hi_b[0] - lo_b[0], 0.0], 0.0)  # beside the base, on the table
    assert not stacked(world)


def test_quaternions_match_mujoco():
    from particlesplat.data.families.robot_assets import import_mujoco
    from particlesplat.policy.control import matrix_to_quat, quat_to_matrix

    mujoco = import_mujoco()
    rng = np.random.default_rng(0)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        want = np.zeros(9)
        mujoco.mju_quat2Mat(want, q)
        R = quat_to_matrix(q)
        np.testing.assert_allclose(R, want.reshape(3, 3), atol=1e-12)
        back = matrix_to_quat(R)
        np.testing.assert_allclose(back, q if q[0] >= 0 else -q, atol=1e-9)


def test_controller_reaches_keyposes():
    """The grasp point arrives within 4 mm of each keypose's position and the hand within 0.05 rad of its turn,
    as MuJoCo's bodies say after the move; the fingers open and close to their limits."""
    from particlesplat.data.families.robot_assets import import_mujoco
    from particlesplat.policy.control import ArmController, Keypose, hand_down, matrix_to_quat, rotation_error

    world = _world("place", 1)
    ctrl = ArmController(import_mujoco(), world.comp)
    for pos, yaw, grip in (((0.0, 0.15, 0.25), 0.3, 0.0), ((-0.1, -0.2, 0.12), 2.4, 1.0), ((0.1, 0.0, 0.2), 1.6, 0.0)):
        R = hand_down(yaw)
        q = matrix_to_quat(R)
        result = ctrl.execute(Keypose(pos, (q[0], q[1], q[2], q[3]), grip))
        eef, rot = ctrl.eef_pose()
        assert result.reached
        assert np.linalg.norm(eef - pos) < 0.004
        assert np.linalg.norm(rotation_error(rot, R)) < 0.05
        fingers = world.arm_state()[1]
        assert abs(abs(fingers).mean() - 0.04 * grip) < 0.002  # fully open (0.04 m) or shut on nothing


@pytest.mark.parametrize(("task", "index"), [("place", 0), ("place", 1), ("stack", 0), ("stack", 1)])
def test_expert_solves(task, index):
    from particlesplat.policy.rollout import expert_decider, run_episode
    from particlesplat.policy.tasks import TASKS

    world = _world(task, index)
    result = run_episode(world, TASKS[task], expert_decider(TASKS[task]), render=False)
    assert result.success
    assert 4 <= len(result.steps) <= 8  # a keypose protocol's pick and place
    kinds = [kp.gripper for _, kp in result.steps]
    assert 0.0 in kinds and kinds[-1] == 1.0  # it closed on the target, and let go


def test_heldout_split_draws_outside_training_colours():
    from particlesplat.data.families.robot_wide import HELDOUT_HUES
    from particlesplat.policy.tasks import hue_of

    world = _world("place", 0, "heldout")
    assert world.roles.count("distractor") >= 2  # one more than the task's least
    for spec in world.specs:
        if spec.rgba is not None:
            h = hue_of(spec.rgba)
            assert any(lo - 1e-6 <= h <= hi + 1e-6 for lo, hi in HELDOUT_HUES), h


@pytest.mark.parametrize("split", ["train", "heldout"])
def test_what_to_pick_is_seen(split):
    """place: the goal pad has the target's colour, and every distractor primitive's hue is MIN_HUE_GAP away from
    it (read back from the compiled model's materials and geoms); stack: no distractor is a box."""
    from particlesplat.policy.tasks import MIN_HUE_GAP, hue_gap, hue_of

    for index in range(4):
        world = _world("place", index, split)
        m = world.comp.model
        pad = m.geom_rgba[m.geom("marker_goal").id]
        target = world.specs[world.index("target")]
        np.testing.assert_allclose(pad, target.rgba, atol=1e-6)
        for spec, role in zip(world.specs, world.roles, strict=True):
            if role == "distractor" and spec.rgba is not None:
                assert hue_gap(hue_of(spec.rgba), hue_of(target.rgba)) >= MIN_HUE_GAP
        stack = _world("stack", index, split)
        assert [s.kind for s, r in zip(stack.specs, stack.roles, strict=True) if r != "distractor"] == ["box", "box"]
        assert all(s.kind != "box" for s, r in zip(stack.specs, stack.roles, strict=True) if r == "distractor")


def test_grasp_yaw_spans_the_narrow_side():
    """The fingers close across a box's narrower side, within a quarter turn of the home yaw."""
    from particlesplat.policy.expert import HOME_YAW, grasp_yaw
    from particlesplat.policy.world import yaw_of

    for index in range(6):
        world = _world("stack", index)
        k = world.index("target")
        yaw = grasp_yaw(world, k)
        assert abs(yaw - HOME_YAW) <= math.pi / 2 + 1e-9
        hx, hy, _ = world.specs[k].half_size
        body = yaw_of(world.poses()[1][k])
        axis = np.array([math.cos(body), math.sin(body)]) if hx <= hy else np.array([-math.sin(body), math.cos(body)])
        assert abs(abs(axis @ [math.cos(yaw), math.sin(yaw)]) - 1.0) < 1e-6


@pytest.mark.parametrize("task,split", [("place", "train"), ("stack", "heldout")])
def test_the_rig_never_sees_the_sky(task, split):
    """The rig's views skip drawing the sky: on several worlds of each task and split they are the same, pixel for
    pixel, as with the sky drawn, and no pixel is left without depth."""
    from particlesplat.data.families.robot_assets import import_mujoco
    from particlesplat.data.families.robot_render import SceneRenderer
    from particlesplat.policy.world import RESOLUTION, RigRenderer

    for index in range(3):
        world = _world(task, index, split)
        rig = RigRenderer(world)
        sky = SceneRenderer(import_mujoco(), world.comp, RESOLUTION, RESOLUTION, skybox=True)
        try:
            a, b = rig.render(), sky.render(world.comp.camera_ids)
        finally:
            rig.close()
            sky.close()
        assert not rig.renderer.skybox
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth) and np.array_equal(a.masks, b.masks)
        assert (a.depth > 0).all()
