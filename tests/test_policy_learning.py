"""The keypose policy: actions round-trip to keyposes, a padded token set reads as its real rows, the head learns a
rule only the right token holds, and ``policy train`` / ``policy eval`` run end to end on tiny data (a closed-loop
rollout reproducible from its seed); a decision's particles sit on the simulator's objects."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
import torch

from particlesplat.policy.control import Keypose, hand_down, matrix_to_quat
from particlesplat.policy.features import (
    ACTION_DIMS,
    OBJECT_DIMS,
    ROBOT_DIMS,
    Step,
    keypose_from_action,
    keypose_target,
)
from particlesplat.policy.head import KeyposePolicy, token_source
from particlesplat.policy.learn import TrainSettings, make_batch, train

needs_sim = pytest.mark.skipif(
    importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None,
    reason="policy tasks need the sim extra",
)


def _step(rng: np.random.Generator, objects: int = 3, goal: bool = True) -> Step:
    boxes = np.sort(rng.uniform(-0.3, 0.3, (objects, 2, 3)), axis=1)
    return Step(
        rng.uniform(-1, 1, 7),
        rng.uniform(0, 0.04, 2),
        1.0,
        np.concatenate([rng.uniform(-0.3, 0.3, 3), [1.0, 0.0, 0.0, 0.0]]),
        boxes,
        rng.uniform(0, 1, (objects, 3)),
        ["box"] * objects,
        rng.uniform(-0.2, 0.2, 3) if goal else np.full(3, np.nan),
        rng.uniform(0, 1, 3),
        0.05,
        rgb=rng.integers(0, 256, (2, 32, 32, 3)).astype(np.uint8),
        depth=rng.uniform(0, 2, (2, 32, 32)).astype(np.float32),
    )


def test_keypose_round_trips_through_an_action():
    for yaw, grip in ((0.3, 1.0), (2.9, 0.0), (-1.2, 1.0)):
        q = matrix_to_quat(hand_down(yaw))
        kp = Keypose((0.1, -0.2, 0.3), (q[0], q[1], q[2], q[3]), grip)
        action = keypose_target(kp.as_array())
        assert action.shape == (ACTION_DIMS,)
        back = keypose_from_action(action)
        np.testing.assert_allclose(back.position, kp.position, atol=1e-6)
        assert abs(abs(np.dot(back.quaternion, kp.quaternion)) - 1.0) < 1e-6
        assert back.gripper == grip


def test_robot_features_ignore_the_quaternions_sign():
    """q and -q are one hand pose (a hand pointing down sits where the sign flips): the same features."""
    from particlesplat.policy.features import robot_features

    rng = np.random.default_rng(4)
    step = _step(rng)
    q = matrix_to_quat(hand_down(1.0))
    step.eef = np.concatenate([[0.1, 0.2, 0.3], q])
    flipped = _step(np.random.default_rng(4))
    flipped.eef = np.concatenate([[0.1, 0.2, 0.3], -q])
    np.testing.assert_allclose(robot_features(step), robot_features(flipped), atol=1e-7)
    assert robot_features(step).shape == (ROBOT_DIMS,)


@pytest.mark.parametrize("kind", ["state", "robot", "particles"])
def test_padding_is_ignored(kind):
    """A step's action does not change when its set is padded with masked rows (a batch with a larger step)."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = KeyposePolicy(token_source(kind, 12)).eval()
    small, large = _step(rng, 2), _step(rng, 5)
    parts = [(rng.normal(size=(n, 12)).astype(np.float32), rng.integers(0, 2, n), np.ones(n, bool)) for n in (3, 7)]
    with torch.no_grad():
        alone = model(make_batch(kind, [small], parts[:1]))
        padded = model(make_batch(kind, [small, large], parts))[:1]
    torch.testing.assert_close(alone, padded, atol=1e-5, rtol=1e-5)


def _viewed(step: Step, size: int = 128) -> Step:
    """``step`` with two size x size RGB-D views of a camera 1 m above the table looking straight down."""
    rng = np.random.default_rng(3)
    step.rgb = rng.integers(0, 256, (2, size, size, 3)).astype(np.uint8)
    step.depth = np.full((2, size, size), 1.0, np.float32)
    K = np.array([[size, 0, size / 2], [0, size, size / 2], [0, 0, 1]], np.float64)
    c2w = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV: +z forward = world down
    c2w[:3, 3] = (0.0, 0.0, 1.0)
    step.intrinsics, step.c2w = np.stack([K, K]), np.stack([c2w, c2w])
    return step


def test_images_make_tokens_per_cell():
    rng = np.random.default_rng(1)
    source = token_source("images")
    batch = make_batch("images", [_viewed(_step(rng)), _viewed(_step(rng))])
    tokens, padding, points = source(batch)
    assert tokens.shape == (2, 2 * 4 * 4, 128) and not padding.any() and points.shape == (2, 2 * 4 * 4, 3)
    assert make_batch("images", [_viewed(_step(rng))])["robot"].shape == (1, ROBOT_DIMS)


@pytest.mark.parametrize("cell", [16, 32])
def test_an_image_cells_point_is_its_pixels_mean_world_point(cell):
    """Analytic: a camera 1 m straight above the table (focal = width, so the view spans 1 m at the table), depth
    1 m everywhere: cell (row r, column c) of ``cell`` px is centred at x = (cell c + cell / 2 - 64) / 128,
    y = -(cell r + cell / 2 - 64) / 128, z = 0; a cell without depth takes the camera's centre."""
    from particlesplat.policy.features import image_points

    step = _viewed(_step(np.random.default_rng(5)))
    step.depth[1, :cell, :cell] = 0.0  # view 1's first cell: no depth
    pts = image_points(step, cell)
    n = (128 // cell) ** 2
    assert pts.shape == (2 * n, 3)
    r, c = np.divmod(np.arange(n), 128 // cell)
    expected = np.stack([(cell * c + cell / 2 - 64) / 128, -(cell * r + cell / 2 - 64) / 128, np.zeros(n)], 1)
    np.testing.assert_allclose(pts[:n], expected, atol=1e-6)
    np.testing.assert_allclose(pts[n], (0.0, 0.0, 1.0), atol=1e-6)
    np.testing.assert_allclose(pts[n + 1 :], expected[1:], atol=1e-6)


def test_state_head_learns_where_the_goal_is():
    """A rule only one token holds: the keypose is the goal pad's centre (its row is flagged, its place among the
    rows random). After a short training the state policy finds it to within 1 cm on steps it never saw: it points
    at the goal's row."""
    rng = np.random.default_rng(2)

    def sample():
        step = _step(rng, int(rng.integers(1, 4)))
        q = matrix_to_quat(hand_down(0.5))
        return step, np.array([*step.goal, *q, 1.0])

    data = [sample() for _ in range(256)]
    model, log = train("state", data, TrainSettings(steps=500, batch=32, lr=1e-3, seed=0))
    assert log.losses[-1] < log.losses[0] / 4
    test = [sample() for _ in range(32)]
    with torch.no_grad():
        pred = model(make_batch("state", [s for s, _ in test])).numpy()
    err = np.linalg.norm(pred[:, :3] - np.stack([k[:3] for _, k in test]), axis=1)
    assert np.median(err) < 0.01, np.median(err)
    assert make_batch("state", [test[0][0]])["objects"].shape[-1] == OBJECT_DIMS


def test_policy_file_round_trip(tmp_path):
    """A particles policy written and read back gives the same actions; a file that is not one is refused in one
    line naming it."""
    from particlesplat.policy.learn import PolicyFileError, load_policy, save_policy

    rng = np.random.default_rng(3)
    data = [(_step(rng), np.array([0.1, 0.0, 0.2, 1.0, 0.0, 0.0, 0.0, 1.0])) for _ in range(8)]
    rows = [
        (rng.normal(size=(5, 12)).astype(np.float32), rng.integers(0, 2, 5), rng.uniform(size=5) < 0.7) for _ in data
    ]
    settings = TrainSettings(steps=2, batch=4, seed=1)
    model, _ = train("particles", data, settings, rows, 12)
    path = tmp_path / "p.pt"
    save_policy(path, model, "particles", "place", settings, {"note": 1})
    back, meta = load_policy(path)
    assert meta["input"] == "particles" and meta["particle_dims"] == 12 and meta["settings"]["steps"] == 2
    with torch.no_grad():
        batch = make_batch("particles", [s for s, _ in data], rows)
        torch.testing.assert_close(model(batch), back(batch))
    (tmp_path / "bad.pt").write_bytes(b"not a policy")
    with pytest.raises(PolicyFileError, match="bad.pt: not a policy file"):
        load_policy(tmp_path / "bad.pt")


@needs_sim
def test_train_and_evaluate_on_tiny_data(tmp_path, capsys):
    from particlesplat.cli.main import main
    from particlesplat.core.errors import UserError

    demos = tmp_path / "demos"
    assert main(["policy", "collect", "--task", "place", "--episodes", "1", "--out", str(demos), "--quiet"]) == 0
    for kind in ("state", "images"):
        out = tmp_path / f"{kind}.pt"
        argv = ["policy", "train", "--input", kind, "--demos", str(demos), "--out", str(out), "--steps", "3"]
        assert main([*argv, "--batch", "4", "--quiet"]) == 0
        assert out.is_file()
    runs = []
    for n in range(2):
        js = tmp_path / f"eval{n}.json"
        argv = ["policy", "eval", "--policy", str(tmp_path / "state.pt"), "--rollouts", "1", "--seed", "5"]
        assert main([*argv, "--json", str(js), "--quiet"]) == 0
        runs.append(json.loads(js.read_text()))
    assert runs[0]["rollouts"] == 1 and runs[0]["input"] == "state" and runs[0]["task"] == "place"
    assert runs[0]["success"] == runs[1]["success"] and runs[0]["decisions"] == runs[1]["decisions"]  # by seed
    assert 1 <= runs[0]["decisions"][0] <= 10
    assert 0 < runs[0]["decision_seconds"][0] < runs[0]["wall_seconds"][0]  # the controller's motion not counted
    low, high = runs[0]["success_interval_95"]
    assert (low, high) == ((0.0, 0.7935) if runs[0]["success"] == [False] else (0.2065, 1.0))  # Wilson, 1 trial
    with pytest.raises(UserError, match="task 'place', not 'stack'"):
        main(["policy", "train", "--task", "stack", "--input", "robot", "--demos", str(demos), "--out", str(out)])


@pytest.mark.parametrize("successes,trials", [(0, 50), (1, 50), (13, 50), (25, 50), (49, 50), (50, 50), (3, 7)])
def test_the_success_interval_is_the_set_of_rates_the_score_test_keeps(successes, trials):
    """Wilson's interval against its definition, by brute force in float64: the rates p on a fine grid where
    |k / n - p| <= z sqrt(p (1 - p) / n)."""
    from particlesplat.policy.evaluate import wilson_interval

    p = np.linspace(0.0, 1.0, 2_000_001)
    kept = p[np.abs(successes / trials - p) <= 1.959964 * np.sqrt(p * (1 - p) / trials)]
    low, high = wilson_interval(successes, trials)
    assert abs(low - kept.min()) <= 1e-6 and abs(high - kept.max()) <= 1e-6
    assert wilson_interval(0, 0) == (0.0, 1.0)


@needs_sim
@pytest.mark.slow
def test_a_decisions_particles_sit_on_its_objects(tmp_path):
    """The shipped robot model, reading one decision's two views as 'particlesplat encode' does, places an object
    within 5 cm of each object the simulator holds (its box centre), the goal pad aside."""
    from particlesplat.cli.main import main
    from particlesplat.policy.episodes import read_episodes
    from particlesplat.policy.features import episode_steps
    from particlesplat.policy.particles import DecisionEncoder

    demos = tmp_path / "demos"
    assert main(["policy", "collect", "--task", "stack", "--episodes", "1", "--out", str(demos), "--quiet"]) == 0
    _, (episode,) = read_episodes(demos)
    step, _ = episode_steps(episode)[0]
    encoder = DecisionEncoder()
    arrays = encoder.arrays(step)
    centres = step.boxes.mean(1)
    found = arrays.object_centroid
    near = [np.linalg.norm(found[:, :2] - c[:2], axis=1).min() < 0.05 for c in centres]
    assert np.mean(near) >= 0.66, (centres, found)
    # a closed-loop decision's rows skip the background and the grouping, and are the arrays' rows exactly
    from particlesplat.policy.particles import particle_rows

    live, cached = encoder.live_rows(step), particle_rows(arrays, encoder.d_obj)
    for a, b in zip(live, cached, strict=True):
        np.testing.assert_array_equal(a, b)
    assert cached[2].any() and (cached[0][~cached[2]] == 0).all()


@pytest.mark.parametrize("kind", ["state", "particles", "images", "robot"])
def test_moving_the_scene_in_the_tables_plane_moves_the_keypose_with_it(kind):
    """The head is blind to where things are in x and y: shifting every point and the grasp point by d (and
    changing the joint angles, which say where the arm is) shifts the predicted position by d, nothing else."""
    torch.manual_seed(1)
    rng = np.random.default_rng(7)
    model = KeyposePolicy(token_source(kind, 12)).eval()
    steps = [_viewed(_step(rng, 3)), _viewed(_step(rng, 2))]
    parts = [(rng.normal(size=(n, 12)).astype(np.float32), rng.integers(0, 2, n), np.ones(n, bool)) for n in (4, 6)]
    batch = make_batch(kind, steps, parts)
    d = torch.tensor([0.13, -0.07])
    moved = {k: v.clone() for k, v in batch.items()}
    moved["robot"][:, 10:12] += d
    moved["robot"][:, :7] = torch.randn(2, 7)
    for key in ("objects", "particles", "images_points"):
        if key in moved:
            moved[key][..., :2] += d
    with torch.no_grad():
        a, b = model(batch), model(moved)
    torch.testing.assert_close(b[:, :2], a[:, :2] + d, atol=1e-5, rtol=0)
    torch.testing.assert_close(b[:, 2:], a[:, 2:], atol=1e-5, rtol=0)


def test_a_box_footprints_turn_is_its_long_sides_yaw_doubled():
    """Analytic: a 6 x 2 cm box turned 30 degrees about z: 1 - 1/3, cos 60, sin 60; turned half a turn more: the
    same; its long side along y (half sizes swapped) reads as turned 90 degrees more; a cylinder: zeros."""
    from particlesplat.policy.features import footprint_turn

    def quat(deg):
        a = np.radians(deg) / 2.0
        return np.array([np.cos(a), 0.0, 0.0, np.sin(a)])

    half = np.array([0.03, 0.01, 0.02])
    expected = [2.0 / 3.0, np.cos(np.radians(60)), np.sin(np.radians(60))]
    np.testing.assert_allclose(footprint_turn("box", quat(30), half), expected, atol=1e-12)
    np.testing.assert_allclose(footprint_turn("box", quat(210), half), expected, atol=1e-12)
    swapped = footprint_turn("box", quat(30), half[[1, 0, 2]])
    np.testing.assert_allclose(swapped, [2.0 / 3.0, np.cos(np.radians(240)), np.sin(np.radians(240))], atol=1e-12)
    assert not footprint_turn("cylinder", quat(30), half).any()
    assert not footprint_turn("box", quat(30), np.full(3, np.nan)).any()


def test_a_hue_turn_keeps_greys_and_colour_distances_and_turns_red_to_green():
    from particlesplat.policy.learn import hue_turn, turn_hues

    R = hue_turn(2.0 * np.pi / 3.0)
    torch.testing.assert_close(R @ R.T, torch.eye(3), atol=1e-6, rtol=0)
    torch.testing.assert_close(R @ torch.tensor([0.4, 0.4, 0.4]), torch.tensor([0.4, 0.4, 0.4]), atol=1e-6, rtol=0)
    torch.testing.assert_close(R @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]), atol=1e-6, rtol=0)
    rng = np.random.default_rng(8)
    batch = make_batch("state", [_step(rng, 3), _step(rng, 2)])
    before = batch["objects"].clone()
    turn_hues("state", batch, np.array([2.0 * np.pi / 3.0, 0.0]))
    colour = slice(9, 12)
    torch.testing.assert_close(batch["objects"][0, :, colour], before[0, :, colour] @ R.T, atol=1e-6, rtol=0)
    torch.testing.assert_close(batch["objects"][1], before[1], atol=1e-6, rtol=0)
    torch.testing.assert_close(batch["objects"][..., :9], before[..., :9])


@needs_sim
@pytest.mark.parametrize("kind", ["state", "particles", "robot"])
def test_the_shipped_place_policies_load_and_act_from_a_seed(kind, tmp_path):
    """assets/policies holds the place task's policies (the table's first task, training seed 0): each loads as
    its input and task, was trained on 100 demonstrations at the default budget, and ``policy eval`` runs one
    rollout of it without training, the same twice from one seed."""
    from pathlib import Path

    from particlesplat.cli.main import main
    from particlesplat.policy.learn import load_policy
    from particlesplat.policy.options import TRAIN_STEPS

    path = Path(__file__).resolve().parents[1] / "assets" / "policies" / f"place-{kind}.pt"
    _, info = load_policy(path)
    assert info["input"] == kind and info["task"] == "place"
    assert info["settings"]["steps"] == TRAIN_STEPS and info["info"]["episodes"] == 100
    if kind == "particles":
        from particlesplat.policy.runs import trained_encoder

        # the model its particles came from is here (the shipped robot model, by its hash): a new robot model ships
        # with this policy trained again on its particles, or with the model it learnt from
        trained_encoder(path, info)
        return  # its rollout encodes every decision (seconds each): the tiny-data test covers the loop
    runs = []
    for n in range(2):
        js = tmp_path / f"{n}.json"
        argv = ["policy", "eval", "--policy", str(path), "--rollouts", "1", "--seed", "1000", "--json", str(js)]
        assert main([*argv, "--quiet"]) == 0
        runs.append(json.loads(js.read_text()))
    assert runs[0]["success"] == runs[1]["success"] and runs[0]["decisions"] == runs[1]["decisions"]


def test_a_particles_policy_finds_its_encoder_on_another_machine(tmp_path):
    """A recorded encoder path that is not here is the shipped robot model when the SHA-256 matches (a policy
    trained in another clone), None recorded is the shipped model while its hash matches, and another model's hash
    is one clear error."""
    from particlesplat.analysis.particle_arrays import file_sha256
    from particlesplat.core.errors import UserError
    from particlesplat.data.families import get_family
    from particlesplat.policy.runs import trained_encoder

    sha = file_sha256(get_family("robot").shipped_model_path())
    elsewhere = str(tmp_path / "gone" / "model.pt")
    assert trained_encoder(tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": elsewhere, "sha256": sha}}}) is None
    assert trained_encoder(tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": None, "sha256": sha}}}) is None
    here = tmp_path / "mine.pt"
    here.write_bytes(b"x")
    assert trained_encoder(tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": str(here)}}}) == str(here)
    with pytest.raises(UserError, match=r"p\.pt: key 'info.encoder.checkpoint': .* is not here"):
        trained_encoder(tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": elsewhere, "sha256": "0" * 64}}})
    # the shipped model replaced since the policy learnt (a recorded hash that is not the shipped model's), or the
    # recorded file changed: an error, not a run on another model's particles
    with pytest.raises(UserError, match=r"p\.pt: key 'info.encoder.sha256': .* not the shipped"):
        trained_encoder(tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": None, "sha256": "0" * 64}}})
    assert trained_encoder(
        tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": str(here), "sha256": file_sha256(here)}}}
    ) == str(here)
    # a relative path is beside the policy (a shipped policy keeps the model it learnt from next to it)
    beside = {"info": {"encoder": {"checkpoint": "mine.pt", "sha256": file_sha256(here)}}}
    assert trained_encoder(tmp_path / "p.pt", beside) == str(here)
    with pytest.raises(UserError, match=r"p\.pt: key 'info.encoder.sha256': .*mine\.pt changed"):
        trained_encoder(tmp_path / "p.pt", {"info": {"encoder": {"checkpoint": str(here), "sha256": "0" * 64}}})


@needs_sim
def test_policy_eval_with_another_model_than_it_learnt_from_is_one_line(tmp_path, capsys):
    """A particles policy whose recorded encoder hash is not the shipped model's: ``policy eval`` ends with one line
    naming the file and the key, exit 2, before any rollout and without a progress bar."""
    from pathlib import Path

    from particlesplat.cli.main import main
    from particlesplat.core.errors import run_command

    shipped = Path(__file__).resolve().parents[1] / "assets" / "policies" / "place-particles.pt"
    payload = torch.load(shipped, weights_only=False)
    payload["info"]["encoder"] = {"checkpoint": None, "sha256": "0" * 64}
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    argv = ["policy", "eval", "--policy", str(bad), "--rollouts", "1", "--seed", "1000"]
    assert run_command("particlesplat policy", lambda: main(argv)) == 2
    err = capsys.readouterr().err
    assert "bad.pt: key 'info.encoder.sha256'" in err and "Traceback" not in err and "rollout" not in err
    assert len(err.strip().splitlines()) == 1


def test_a_decision_scene_holds_the_arm_within_its_limits(tmp_path):
    """The simulator's joint limits are soft (a joint pressed against one overshot it by 0.8 mrad in a rollout):
    a decision's scene holds the joints within the Panda's limits, which every scene reader checks, and keeps
    the others as they are."""
    from particlesplat.data.pose_ranges import PANDA_JOINT_LIMITS, check_limits
    from particlesplat.data.scene_meta import read_scene_json
    from particlesplat.policy.particles import write_decision_scene

    step = _viewed(_step(np.random.default_rng(4)))
    step.robot_base = np.eye(4)
    step.joints = np.array([0.0, 0.2, 0.0, -2.0, 0.0, PANDA_JOINT_LIMITS[5][1] + 8e-4, PANDA_JOINT_LIMITS[6][0] - 1e-3])
    write_decision_scene(tmp_path / "scene", step)
    joints = read_scene_json(tmp_path / "scene" / "scene.json")["arm_joints_rad"]
    check_limits(joints, "arm_joints_rad", "scene.json")
    assert joints[5] == PANDA_JOINT_LIMITS[5][1] and joints[6] == PANDA_JOINT_LIMITS[6][0]
    assert joints[:5] == [0.0, 0.2, 0.0, -2.0, 0.0]
