"""Write a robot-workspace dataset: ``OUT/{train,val,test,heldout}/scene_NNNNN`` (test and held-out scenes with
ground-truth edits), of the narrow world (:mod:`.robot`) or the wide one (:mod:`.robot_wide`; only it has a
held-out split).

Every scene draws from its own RNG seeded by ``(seed, split, index)`` (and its edits from
``(seed, split, index, 1)``), so a scene does not depend on the worker count, the other splits' sizes or
resuming. A scene is written under a hidden temporary name and renamed when complete; finished scenes
are skipped when the command runs again. Each worker process holds its own MuJoCo model and GL context.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from particlesplat.core.errors import OptionError
from particlesplat.data.synth import (
    SPLIT_IDS,
    check_manifest,
    check_settings,
    missing_scenes,
    owned_dataset,
    run_tasks,
    scene_name,
)

from .robot import ARM_POSES, CAMERA_RIGS, FORMAT_VERSION, GENERATOR, WORLDS, RobotSceneConfig, write_robot_scene
from .robot_assets import assets_dir, import_mujoco

EDIT_SPLITS = ("test", "heldout")  # splits whose scenes carry ground-truth edits


def scene_rngs(
    seed: int, split: str, index: int, edits: bool
) -> tuple[np.random.Generator, np.random.Generator | None]:
    """The scene's RNG and, when ``edits``, its edits' RNG; independent of every other scene."""
    ids = [seed, SPLIT_IDS[split], index]
    rng = np.random.default_rng(np.random.SeedSequence(ids))
    return rng, (np.random.default_rng(np.random.SeedSequence([*ids, 1])) if edits else None)


def write_scene(out: Path, seed: int, split: str, index: int, config: RobotSceneConfig, edits: bool) -> dict:
    """Write scene ``index`` of ``split`` under ``out``; returns seconds per stage."""
    rng, edits_rng = scene_rngs(seed, split, index, edits)
    meta = {"seed": seed, "split": split, "index": index}
    folder = out / split / scene_name(index)
    if config.world == "wide":
        from . import robot_wide

        build = partial(robot_wide.build_wide_scene, heldout=split == "heldout")
        return write_robot_scene(folder, rng, config, meta, edits_rng, build, robot_wide.GENERATOR)
    return write_robot_scene(folder, rng, config, meta, edits_rng)


def manifest(seed: int, config: RobotSceneConfig) -> dict:
    """What ``synth.json`` records of a robot dataset (a narrow dataset's as before the wide world existed, so
    those datasets still resume)."""
    settings = asdict(config)
    if config.world == "narrow":
        settings.pop("world")
        return {"generator": GENERATOR, "format_version": FORMAT_VERSION, "seed": seed, **settings}
    from . import robot_wide

    settings.pop("arm")  # the wide world draws its own arm poses
    return {
        "generator": robot_wide.GENERATOR,
        "format_version": FORMAT_VERSION,
        "family": "robot",
        "seed": seed,
        **settings,
    }


def _work(task: tuple) -> dict:
    out, seed, split, index, config, edits = task
    start = time.perf_counter()
    times = write_scene(Path(out), seed, split, index, config, edits)
    return {**times, "total": time.perf_counter() - start}


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)
    import_mujoco()


def generate(
    out: Path,
    counts: dict[str, int],
    seed: int,
    config: RobotSceneConfig,
    workers: int = 2,
    progress: bool = True,
    edits: tuple[str, ...] = EDIT_SPLITS,
) -> list[dict]:
    """Write ``counts[split]`` robot scenes per split under ``out`` (scenes of the ``edits`` splits with their
    ground-truth edits); skip scenes that exist. Returns each new scene's seconds per stage (worker wall time).

    Raises:
        OptionError: bad settings; SimSetupError: MuJoCo, robosuite's assets or GL missing (both UserErrors).
    """
    if config.width != config.height:
        raise OptionError(f"--res: robot scenes are square, got {config.width}x{config.height}")
    check_settings(out, counts, seed, config.width, workers)
    if config.cameras not in CAMERA_RIGS:
        raise OptionError(f"--cameras must be one of {', '.join(CAMERA_RIGS)}, got {config.cameras!r}")
    if config.arm not in ARM_POSES:
        raise OptionError(f"--arm must be one of {', '.join(ARM_POSES)}, got {config.arm!r}")
    if config.world not in WORLDS:
        raise OptionError(f"--world must be one of {', '.join(WORLDS)}, got {config.world!r}")
    if config.world == "wide" and config.arm != "home":
        raise OptionError(
            f"--arm {config.arm}: the wide world (the default) draws its own arm poses; leave --arm out, or add "
            "--world narrow"
        )
    if config.world == "narrow" and counts.get("heldout", 0):
        raise OptionError("--heldout: only the wide world (--world wide) has a held-out split")
    assets_dir()  # one line naming what to install, before any folder is made
    import_mujoco()
    with owned_dataset(out):
        check_manifest(out, manifest(seed, config))
        tasks = [(str(out), seed, split, i, config, split in edits) for split, i in missing_scenes(out, counts)]
        total = sum(counts.values())
        bar = tqdm(total=total, initial=total - len(tasks), desc="synth robot", unit="scene", disable=not progress)
        # forked workers: the parent has imported mujoco but made no GL context, so each child opens its own
        return run_tasks(tasks, _work, _init_worker, workers, bar)


def generate_family(out: Path, counts: dict[str, int], seed: int, options: argparse.Namespace) -> list[float]:
    """The robot family's generator entry (:class:`particlesplat.data.families.Family`): :func:`generate` with
    ``synth``'s ``options`` (``res``, ``workers``, ``cameras``, ``arm``, ``world``); seconds per new scene."""
    config = RobotSceneConfig(options.res, options.res, cameras=options.cameras, arm=options.arm, world=options.world)
    return [t["total"] for t in generate(out, counts, seed, config, options.workers)]
