"""Record the scripted expert's demonstrations of a task into a folder (:mod:`.episodes`' layout).

Episode ``i`` draws its world from its own RNG (:func:`.tasks.episode_rng`: the seed, the task, the split and
``i``), so an episode is the same whatever else the folder holds: a run that stopped (Ctrl-C, SIGTERM, a crash)
resumes by running the same command again, which records only the missing episodes. Each episode file is written
to a temporary name and renamed when complete; temporaries a killed run left are removed first. The folder is
locked while a run writes it (a second run into it is refused in one line). Every episode is kept, the expert's
failures too (``meta.success`` says which); a learner reads the successes (:func:`.episodes.read_episodes`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from particlesplat.core.errors import short_repr

from .episodes import FORMAT, FORMAT_VERSION, MANIFEST, EpisodeFormatError, episode_files, episode_name
from .options import DEFAULT_TASK, check_collect_options
from .tasks import TASKS, Task, build_task_world, episode_rng
from .world import CAMERA_NAMES, RESOLUTION, TaskWorld


@dataclass
class CollectSummary:
    """What a folder holds after a run: ``episodes`` in all, ``successes`` among them, ``new`` recorded by this
    run, and this run's wall seconds per new episode (``seconds``)."""

    episodes: int
    successes: int
    new: int
    seconds: list[float]

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else 0.0


def check_options(task: str, episodes: int, seed: int, split: str) -> Task:
    """The task, or OptionError naming the option (:func:`.options.check_collect_options`)."""
    check_collect_options(task, episodes, seed, split)
    return TASKS[task]


def manifest(task: str, seed: int, split: str) -> dict:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "task": task,
        "split": split,
        "seed": seed,
        "resolution": RESOLUTION,
        "cameras": list(CAMERA_NAMES),
    }


def _check_manifest(out: Path, want: dict) -> None:
    """Write ``want`` as the folder's manifest, or refuse a folder recorded with other settings (one line)."""
    from particlesplat.core.atomic import atomic_write
    from particlesplat.core.jsonfile import read_json

    path = out / MANIFEST
    if path.exists():
        have = read_json(path, error=EpisodeFormatError)
        if not isinstance(have, dict):
            raise EpisodeFormatError(f"{path}: expected a JSON object, got {type(have).__name__}")
        for key, value in want.items():
            if have.get(key) != value:
                raise EpisodeFormatError(
                    f"{path}: key '{key}' is {short_repr(have.get(key))} but this run uses {value!r}; use another "
                    "output folder or the same settings to resume"
                )
        return
    if out.is_dir() and any(out.iterdir()):
        names = [p.name for p in out.iterdir() if p.name != ".lock"]
        if names:
            raise EpisodeFormatError(
                f"{out}: holds {names[0][:80]!r} but no {MANIFEST}: not a demonstrations folder; use another one"
            )
    import json

    with atomic_write(path, "w") as f:
        json.dump(want, f, indent=1)


def world_meta(world: TaskWorld) -> dict:
    """What an episode's ``meta`` records of its world: objects (kind, role, half size, colour, texture), the
    goal pad's radius and colour, the robot's base, the gripper, lights and surfaces."""
    setup = world.setup
    objects = [
        {
            "kind": s.kind,
            "role": role,
            "half_size": None if s.half_size is None else list(s.half_size),
            "rgba": None if s.rgba is None else list(s.rgba),
            "texture": s.texture,
        }
        for s, role in zip(world.specs, world.roles, strict=True)
    ]
    surfaces = {
        name: None if s is None else {"texture": s.texture, "rgba": list(s.rgba)}
        for name, s in (("table", setup.table), ("floor", setup.floor), ("walls", setup.walls))
    }
    goal_rgba = None
    if world.goal is not None:
        m = world.comp.model
        goal_rgba = [float(v) for v in m.geom_rgba[m.geom("marker_goal").id]]
    return {
        "objects": objects,
        "goal_radius": world.goal_radius,
        "goal_rgba": goal_rgba,
        "robot_base": world.comp.robot_base.tolist(),
        "gripper_name": setup.gripper,
        "lights": None if setup.lights is None else dict(vars(setup.lights)),
        "surfaces": surfaces,
    }


def record_episode(task: Task, seed: int, split: str, index: int) -> tuple[dict[str, np.ndarray], dict]:
    """Build episode ``index``'s world, run the expert in it and return its arrays and meta (:mod:`.episodes`)."""
    from .rollout import expert_decider, run_episode

    world = build_task_world(episode_rng(seed, task.name, split, index), task, split)
    result = run_episode(world, task, expert_decider(task))
    if result.final is None or not result.steps:
        raise RuntimeError(f"episode {index}: the expert made no decision")
    obs = [o for o, _ in result.steps]
    final = result.final
    arrays: dict[str, np.ndarray] = {
        "rgb": np.stack([o.rgb for o in obs]),  # type: ignore[misc]
        "depth": np.stack([o.depth for o in obs]),  # type: ignore[misc]
        "masks": np.stack([o.masks for o in obs]),  # type: ignore[misc]
        "intrinsics": np.stack([c.K.double().numpy() for c in world.cameras]),
        "c2w": np.stack([c.c2w.double().numpy() for c in world.cameras]),
        "joints": np.stack([o.joints for o in obs]),
        "fingers": np.stack([o.fingers for o in obs]),
        "gripper": np.array([o.gripper for o in obs]),
        "eef": np.stack([o.eef for o in obs]),
        "keypose": np.stack([k.as_array() for _, k in result.steps]),
        "object_positions": np.stack([o.object_positions for o in obs]),
        "object_quaternions": np.stack([o.object_quaternions for o in obs]),
        "object_boxes": np.stack([o.object_boxes for o in obs]),
        "sim_time": np.array([o.sim_time for o in obs]),
        "final_joints": final.joints,
        "final_fingers": final.fingers,
        "final_eef": final.eef,
        "final_object_positions": final.object_positions,
        "final_object_quaternions": final.object_quaternions,
        "final_object_boxes": final.object_boxes,
        "goal": np.full(3, np.nan) if world.goal is None else np.asarray(world.goal, dtype=np.float64),
    }
    meta = {
        "format_version": FORMAT_VERSION,
        "task": task.name,
        "split": split,
        "seed": seed,
        "index": index,
        "success": result.success,
        "reached": result.reached,
        "steps": len(result.steps),
        "wall_seconds": round(result.wall_seconds, 3),
        "sim_seconds": round(result.sim_seconds, 3),
        **world_meta(world),
    }
    return arrays, meta


def _successes(out: Path) -> tuple[int, int]:
    """(episodes, the expert's successes among them) of the folder, from each file's meta."""
    from .episodes import read_episode_meta

    files = episode_files(out)
    return len(files), sum(bool(read_episode_meta(p)["success"]) for p in files)


def collect(
    out: Path, task: str = DEFAULT_TASK, episodes: int = 100, seed: int = 0, split: str = "train", progress: bool = True
) -> CollectSummary:
    """Record episodes 0..``episodes``-1 of ``task`` into ``out`` (those already there are kept).

    Raises:
        OptionError: a bad option; EpisodeFormatError: ``out`` holds another run's episodes or other files;
        SimSetupError: MuJoCo, robosuite's assets or a headless GL missing (all UserErrors: one line).
    """
    from tqdm import tqdm

    from particlesplat.core.atomic import stale_temporaries
    from particlesplat.data.families.robot_assets import assets_dir, import_mujoco
    from particlesplat.data.synth import owned_dataset

    spec = check_options(task, episodes, seed, split)
    assets_dir()  # one line naming what to install, before any folder is made
    import_mujoco()
    out.mkdir(parents=True, exist_ok=True)
    seconds: list[float] = []
    with owned_dataset(out, "episodes"):
        _check_manifest(out, manifest(task, seed, split))
        for tmp in stale_temporaries(out):
            tmp.unlink()
        todo = [i for i in range(episodes) if not (out / episode_name(i)).is_file()]
        bar = tqdm(
            total=episodes, initial=episodes - len(todo), desc=f"collect {task}", unit="episode", disable=not progress
        )
        from .episodes import write_episode

        try:
            for i in todo:
                start = time.perf_counter()
                arrays, meta = record_episode(spec, seed, split, i)
                write_episode(out / episode_name(i), arrays, meta)
                seconds.append(time.perf_counter() - start)
                bar.update(1)
        finally:
            bar.close()
        total, successes = _successes(out)
    return CollectSummary(total, successes, len(seconds), seconds)
