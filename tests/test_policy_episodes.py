"""Demonstrations on disk: the episode layout round trip, files that do not hold it refused in one line naming the
file and the array, and ``particlesplat policy collect`` end to end (its views against the simulator's objects,
the same keyposes as an unrecorded run of the seed, resuming, a folder of other settings refused)."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from particlesplat.policy.episodes import (
    ARRAYS,
    EpisodeFormatError,
    read_episode,
    read_episode_meta,
    write_episode,
)

T, K, H, W = 3, 2, 8, 6


def _arrays(rng: np.random.Generator) -> dict[str, np.ndarray]:
    sizes = {"T": T, "K": K, "H": H, "W": W}
    out = {}
    for name, (kind, shape) in ARRAYS.items():
        dims = tuple(sizes[s] if isinstance(s, str) else s for s in shape)
        if kind == "u1":
            out[name] = rng.integers(0, 256, dims).astype(np.uint8)
        else:
            out[name] = rng.normal(size=dims).astype(np.dtype(kind))
    return out


def _meta() -> dict:
    return {
        "task": "place",
        "split": "train",
        "seed": 1,
        "index": 4,
        "success": True,
        "steps": T,
        "objects": [{"kind": "box", "role": "target"}, {"kind": "milk", "role": "distractor"}],
    }


def test_layout_round_trip(tmp_path):
    arrays = _arrays(np.random.default_rng(0))
    path = tmp_path / "episode_00004.npz"
    write_episode(path, arrays, _meta())
    back = read_episode(path)
    assert set(back.arrays) == set(ARRAYS)
    for name, a in arrays.items():
        assert back[name].dtype == np.dtype(ARRAYS[name][0])
        np.testing.assert_array_equal(back[name], a)
    assert back.meta == _meta() and back.steps == T and back.success
    assert read_episode_meta(path) == _meta()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left beside it


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda a, m: a.pop("keypose"), "missing array 'keypose'"),
        (lambda a, m: a.__setitem__("joints", np.zeros((T, 6))), "array 'joints': axis 1 is 6, expected 7"),
        (lambda a, m: a.__setitem__("object_positions", np.zeros((T + 1, K, 3))), "'object_positions': axis 0"),
        (lambda a, m: a.__setitem__("rgb", np.zeros((T, 2, H, W, 3), np.float32)), "array 'rgb': expected uint8"),
        (lambda a, m: a["eef"].__setitem__((0, 0), np.nan), "array 'eef': holds values that are not finite"),
        (lambda a, m: m.__setitem__("steps", T + 1), "meta: key 'steps'"),
        (lambda a, m: m.pop("objects"), "meta: missing key 'objects'"),
    ],
)
def test_bad_episodes_refused(tmp_path, change, match):
    """A file whose arrays disagree with the layout is refused on reading, naming it and the array or key (written
    here with numpy directly, as another program might)."""
    arrays, meta = _arrays(np.random.default_rng(1)), _meta()
    change(arrays, meta)
    path = tmp_path / "episode_00000.npz"
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)  # type: ignore[arg-type]
    with pytest.raises(EpisodeFormatError, match=match) as e:
        read_episode(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(EpisodeFormatError):  # and never written
        write_episode(tmp_path / "out.npz", arrays, meta)
    assert not (tmp_path / "out.npz").exists()


def test_not_an_npz_refused(tmp_path):
    path = tmp_path / "episode_00000.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(EpisodeFormatError, match="not a readable .npz"):
        read_episode(path)


needs_sim = pytest.mark.skipif(
    importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None,
    reason="policy tasks need the sim extra",
)


def _lift(depth: np.ndarray, K: np.ndarray, c2w: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """World points (N, 3) of ``pixels`` (N, 2) rows and columns of a planar depth map, OpenCV camera."""
    v, u = pixels[:, 0], pixels[:, 1]
    z = depth[v, u].astype(np.float64)
    rays = np.linalg.inv(K) @ np.stack([u + 0.5, v + 0.5, np.ones_like(z)])
    cam = rays * z
    return (c2w[:3, :3] @ cam + c2w[:3, 3:4]).T


@needs_sim
def test_collect_records_what_the_simulator_holds(tmp_path, capsys):
    from particlesplat.cli.main import main
    from particlesplat.core.errors import UserError
    from particlesplat.policy.episodes import read_episodes
    from particlesplat.policy.rollout import expert_decider, run_episode
    from particlesplat.policy.tasks import TASKS, build_task_world, episode_rng
    from particlesplat.policy.world import RESOLUTION

    out = tmp_path / "demos"
    argv = ["policy", "collect", "--task", "stack", "--episodes", "1", "--seed", "3", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    manifest, episodes = read_episodes(out)
    assert manifest["task"] == "stack" and len(episodes) == 1
    ep = episodes[0]
    assert ep["rgb"].shape == (ep.steps, 2, RESOLUTION, RESOLUTION, 3) and ep.success
    # each view's object pixels, lifted by the recorded depth and cameras, lie in that object's box at that step
    world = build_task_world(episode_rng(3, "stack", "train", 0), TASKS["stack"], "train")
    for view in range(2):
        masks, depth = ep["masks"][0, view], ep["depth"][0, view]
        for k in range(len(world.specs)):
            pixels = np.argwhere(masks == k + 1)
            if len(pixels) < 5:
                continue
            points = _lift(depth, ep["intrinsics"][view], ep["c2w"][view], pixels)
            lo, hi = world.box(k)
            inside = np.all((points >= lo - 0.004) & (points <= hi + 0.004), axis=1)
            assert inside.mean() > 0.97, (view, k, inside.mean())
    np.testing.assert_allclose(ep["object_positions"][0], world.poses()[0], atol=1e-9)
    np.testing.assert_allclose(ep["object_boxes"][0], [np.stack(world.box(k)) for k in range(len(world.specs))])
    # the same keyposes and outcome as a run of the same episode that renders nothing
    result = run_episode(world, TASKS["stack"], expert_decider(TASKS["stack"]), render=False)
    np.testing.assert_array_equal(ep["keypose"], np.stack([k.as_array() for _, k in result.steps]))
    np.testing.assert_array_equal(ep["final_object_positions"], result.final.object_positions)
    assert ep.success == result.success
    # running it again records nothing and changes nothing; other settings are refused, naming the key
    before = (out / "episode_00000.npz").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv) == 0
    assert "1 episodes" in capsys.readouterr().out
    assert (out / "episode_00000.npz").stat().st_mtime_ns == before
    with pytest.raises(UserError, match="collect.json: key 'seed' is 3 but this run uses 4"):
        main([a if a != "3" else "4" for a in argv])
