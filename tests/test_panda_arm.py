"""The Panda's forward kinematics against MuJoCo's own bodies (robosuite's arm model, every gripper), the room
the arm takes against the simulator's arm geometry, and the capsule distance against a brute force."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch

from particlesplat.core.panda_arm import (
    GRIPPER_REACH,
    arm_capsules,
    capsule_distance,
    link_frames,
    pack_arm_state,
)

SIM = importlib.util.find_spec("mujoco") is not None and importlib.util.find_spec("robosuite") is not None
needs_sim = pytest.mark.skipif(not SIM, reason="needs the sim extra (mujoco, robosuite)")
LINKS = ["robot_base"] + [f"robot_link{i}" for i in range(1, 8)] + ["robot_right_hand"]


def _composition(gripper: str):
    import mujoco

    from particlesplat.data.families.robot_assets import assets_dir
    from particlesplat.data.families.robot_compose import WorldSetup, compose

    return mujoco, compose(mujoco, assets_dir(None), [], [], (8, 8), WorldSetup(frame="robosuite", gripper=gripper))


@needs_sim
@pytest.mark.parametrize("gripper", sorted(GRIPPER_REACH))
def test_link_frames_match_the_simulated_bodies(gripper):
    """Every link's pose from the joint angles and the base equals MuJoCo's to 1e-9 m over random joint angles
    within the limits."""
    mujoco, comp = _composition(gripper)
    m, d = comp.model, comp.data
    rng = np.random.default_rng(3)
    for _ in range(10):
        q = rng.uniform(comp.arm_range[:, 0], comp.arm_range[:, 1])
        d.qpos[comp.arm_qpos] = q
        mujoco.mj_forward(m, d)
        frames = link_frames(q, comp.robot_base)
        for frame, name in zip(frames, LINKS, strict=True):
            body = m.body(name).id
            np.testing.assert_allclose(frame[:3, 3], d.xpos[body], atol=1e-9)
            np.testing.assert_allclose(frame[:3, :3], d.xmat[body].reshape(3, 3), atol=1e-9)


@needs_sim
@pytest.mark.parametrize("gripper", sorted(GRIPPER_REACH))
def test_capsules_hold_the_simulated_arm_and_gripper(gripper):
    """Points sampled on the arm's and the gripper's visible geoms (MuJoCo's geom centres, and their bounding
    spheres' poles along the link) lie inside the capsules, for random poses."""
    mujoco, comp = _composition(gripper)
    m, d = comp.model, comp.data
    rng = np.random.default_rng(4)
    visible = [
        g
        for g in range(m.ngeom)
        if m.body(m.geom_bodyid[g]).name.startswith(("robot_link", "robot_right_hand", "robot_gripper"))
        and m.geom_group[g] == 1
    ]
    assert visible
    for _ in range(10):
        q = rng.uniform(comp.arm_range[:, 0], comp.arm_range[:, 1])
        d.qpos[comp.arm_qpos] = q
        mujoco.mj_forward(m, d)
        starts, ends, radii = (torch.from_numpy(a) for a in arm_capsules(q, comp.robot_base, gripper))
        centres = torch.from_numpy(d.geom_xpos[visible].copy())
        assert bool((capsule_distance(centres, starts, ends, radii) < 0).all())


def test_capsule_distance_against_a_brute_force():
    """The distance to a segment minus the radius equals the least distance to 2001 points along the segment."""
    g = torch.Generator().manual_seed(0)
    starts, ends = (
        torch.randn(4, 3, generator=g, dtype=torch.float64),
        torch.randn(4, 3, generator=g, dtype=torch.float64),
    )
    radii = torch.rand(4, generator=g, dtype=torch.float64) * 0.2
    pts = torch.randn(50, 3, generator=g, dtype=torch.float64) * 2
    t = torch.linspace(0, 1, 2001, dtype=torch.float64)
    along = starts[:, None] + t[None, :, None] * (ends - starts)[:, None]  # (4, 2001, 3)
    brute = ((pts[:, None, None] - along[None]).norm(dim=-1).min(dim=2).values - radii).min(dim=1).values
    np.testing.assert_allclose(capsule_distance(pts, starts, ends, radii), brute, atol=1e-6)


def test_packed_state_defaults_and_refusals():
    """A state without a base gets robosuite's; an unknown gripper the largest room; 6 joints are refused."""
    s = pack_arm_state([0.0] * 7, None, None)
    assert len(s) == 21 and s[7:19] == [1.0, 0.0, 0.0, -0.56, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.112]
    assert s[19] == max(GRIPPER_REACH.values())
    assert pack_arm_state([0.0] * 7, None, "panda")[19] == GRIPPER_REACH["panda"]
    with pytest.raises(ValueError, match="7 joint angles"):
        pack_arm_state([0.0] * 6, None, None)


def test_particles_whose_gaussians_the_arm_holds_are_the_robot_s():
    """Two particles: one whose Gaussians sit around the hand (placed by the kinematics), one on the table 0.4 m in
    front of the base. Only the first is the robot's; without a robot state, neither is."""
    from particlesplat.core.gaussians import Gaussians
    from particlesplat.editing.grouping import robot_particles
    from particlesplat.model import Particles

    q = [0.0, 0.3, 0.0, -2.0, 0.0, 2.3, 0.8]
    state = torch.tensor(pack_arm_state(q, None, "panda"))
    base = np.eye(4)
    base[:3] = np.asarray(state[7:19]).reshape(3, 4)
    hand = torch.from_numpy(link_frames(q, base)[-1, :3, 3]).float()
    g = torch.Generator().manual_seed(0)
    near = hand + 0.02 * torch.randn(20, 3, generator=g)
    table = torch.tensor([-0.16, 0.0, 0.03]) + 0.02 * torch.randn(20, 3, generator=g)
    means = torch.cat([near, table])
    n = len(means)
    gauss = Gaussians(
        means,
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), 0.01),
        torch.full((n,), 0.9),
        torch.zeros(n, 1, 3),
        torch.cat([torch.zeros(20), torch.ones(20)]).long(),
    )
    rows = {k: torch.zeros(2, w) for k, w in (("z_p", 2), ("z_s", 2), ("z_d", 1), ("z_e", 1), ("z_t", 1), ("z_f", 4))}
    particles = Particles(**rows, view=torch.zeros(2, dtype=torch.long), background=torch.zeros(1, 1, 1, 1))
    assert robot_particles(particles, gauss, state).tolist() == [True, False]
    assert robot_particles(particles, gauss, None).tolist() == [False, False]
