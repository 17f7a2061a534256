"""Write a robot-workspace dataset: ``OUT/{train,val,test}/scene_NNNNN`` (test scenes with ground-truth edits).

Every scene draws from its own RNG seeded by ``(seed, split, index)`` (and its edits from
``(seed, split, index, 1)``), so a scene does not depend on the worker count, the other splits' sizes or
resuming. A scene is written under a hidden temporary name and renamed when complete; finished scenes
are skipped when the command runs again. Each worker process holds its own MuJoCo model and GL context.
"""

from __future__ import annotations

import multiprocessing as mp
import shutil
import time
from dataclasses import asdict
from pathlib import Path
from types import MappingProxyType

import numpy as np
from tqdm import tqdm

from particlesplat.data.synth import check_manifest

from .robot import ARM_POSES, CAMERA_RIGS, FORMAT_VERSION, GENERATOR, RobotSceneConfig, write_robot_scene
from .robot_assets import assets_dir, import_mujoco

SPLITS = ("train", "val", "test")
SPLIT_IDS = MappingProxyType({"train": 0, "val": 1, "test": 2})
EDIT_SPLITS = ("test",)  # splits whose scenes carry ground-truth edits
MANIFEST = "synth.json"


def scene_name(index: int) -> str:
    return f"scene_{index:05d}"


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
    return write_robot_scene(out / split / scene_name(index), rng, config, meta, edits_rng)


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
        ValueError: bad settings; SimSetupError (a ValueError): MuJoCo, robosuite's assets or GL missing.
    """
    if seed < 0:
        raise ValueError(f"--seed must be >= 0, got {seed}")
    if config.width < 8 or config.height < 8:
        raise ValueError(f"--res must be >= 8, got {config.width}")
    if config.cameras not in CAMERA_RIGS:
        raise ValueError(f"--cameras must be one of {', '.join(CAMERA_RIGS)}, got {config.cameras!r}")
    if config.arm not in ARM_POSES:
        raise ValueError(f"--arm must be one of {', '.join(ARM_POSES)}, got {config.arm!r}")
    if any(n < 0 for n in counts.values()):
        raise ValueError(f"scene counts must be >= 0, got {counts}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a folder")
    assets_dir()  # one line naming what to install, before any folder is made
    import_mujoco()
    check_manifest(out, {"generator": GENERATOR, "format_version": FORMAT_VERSION, "seed": seed, **asdict(config)})
    tasks = []
    for split in SPLITS:
        split_dir = out / split
        if split_dir.is_dir():
            for p in split_dir.glob(".scene_*.tmp"):
                shutil.rmtree(p, ignore_errors=True)
        for index in range(counts.get(split, 0)):
            if not (split_dir / scene_name(index)).is_dir():
                tasks.append((str(out), seed, split, index, config, split in edits))
    total = sum(counts.values())
    bar = tqdm(total=total, initial=total - len(tasks), desc="synth robot", unit="scene", disable=not progress)
    times: list[dict] = []
    try:
        if workers <= 1 or len(tasks) <= 1:
            for task in tasks:
                times.append(_work(task))
                bar.update(1)
        else:
            # fork: the parent has imported mujoco but made no GL context, so each child opens its own
            method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
            with mp.get_context(method).Pool(workers, initializer=_init_worker) as pool:
                for t in pool.imap_unordered(_work, tasks):
                    times.append(t)
                    bar.update(1)
    finally:
        bar.close()
    return times
