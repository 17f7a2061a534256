"""``particlesplat synth``: write the tabletop dataset (train/ val/ test/ scene folders).

Every scene draws from its own RNG seeded by ``(seed, split, index)``, so a scene does not
depend on the worker count, on the other splits' sizes, or on resuming. A scene is written
into a hidden temporary folder and renamed into place when complete, so an interrupted run
leaves only whole scenes, and running the same command again skips them.
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing as mp
import os
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import MappingProxyType
from typing import Any, TypeVar

import numpy as np
import torch
from tqdm import tqdm

from particlesplat.core.atomic import atomic_write, temp_sibling
from particlesplat.core.camera import Camera
from particlesplat.core.errors import Interrupted, OptionError, UserError, stop_signal_handler
from particlesplat.core.limits import check_memory
from particlesplat.core.runlock import RunLock
from particlesplat.data.families import tabletop
from particlesplat.data.folders import SPLITS
from particlesplat.data.scene_files import write_scene_files

MAX_RES = 4096  # a scene image may have at most 4096 x 4096 pixels (particlesplat.data.scene.MAX_IMAGE_PIXELS)
# peak bytes a worker holds per pixel of its scene (renders of 21 views in float64 and their PNG encodings): 9.4 GB
# measured at --res 4100 with one worker, ~560 bytes a pixel
SYNTH_BYTES_PER_PIXEL = 560
SPLIT_IDS = MappingProxyType({"train": 0, "val": 1, "test": 2, "heldout": 3})
FORMAT_VERSION = 1
MANIFEST = "synth.json"
T = TypeVar("T")


def scene_name(index: int) -> str:
    return f"scene_{index:05d}"


def scene_rng(seed: int, split: str, index: int) -> np.random.Generator:
    """The RNG of one scene, independent of every other scene."""
    return np.random.default_rng(np.random.SeedSequence([seed, SPLIT_IDS[split], index]))


def scene_cameras(scene: tabletop.TabletopScene, res: int) -> list[Camera]:
    """The scene's 21 cameras (float64, OpenCV) on its arc."""
    return [
        Camera.orbit(
            tabletop.LOOK_AT,
            float(az),
            scene.elevation_deg,
            scene.distance,
            fov_y_deg=tabletop.FOV_Y_DEG,
            width=res,
            height=res,
            dtype=torch.float64,
        )
        for az in scene.azimuths_deg()
    ]


def write_scene(folder: Path, seed: int, split: str, index: int, res: int) -> None:
    """Render scene ``index`` of ``split`` and write it as a complete folder at ``folder``.

    The folder is built under a temporary name in the same parent and renamed at the end.
    """
    scene = tabletop.sample_scene(scene_rng(seed, split, index))
    write_tabletop(folder, scene, res, {"seed": seed, "split": split, "index": index})


def write_tabletop(folder: Path, scene: tabletop.TabletopScene, res: int, meta: dict) -> None:
    """Render ``scene``'s 21 views at ``res`` and write them as a complete scene folder at ``folder``
    (built under a temporary name and renamed at the end); ``meta`` goes into scene.json."""
    cams = scene_cameras(scene, res)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(folder)
    tmp.mkdir()  # honours the umask (tempfile.mkdtemp would leave the finished scene folder 0700)
    try:
        views = [tabletop.render_view(scene, cam.K.numpy(), cam.c2w.numpy(), res, res) for cam in cams]
        meta = {"generator": "particlesplat.data.synth", "format_version": FORMAT_VERSION, **meta, **scene.to_json()}
        write_scene_files(
            tmp,
            cams,
            [np.round(rgb * 255.0).astype(np.uint8) for rgb, _, _ in views],
            [depth for _, depth, _ in views],
            [mask.astype(np.uint8) for _, _, mask in views],
            meta,
        )
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _work(task: tuple[str, int, int, int, str]) -> float:
    split, index, seed, res, out = task
    start = time.perf_counter()
    write_scene(Path(out) / split / scene_name(index), seed, split, index, res)
    return time.perf_counter() - start


def _init_worker() -> None:
    torch.set_num_threads(1)


@contextmanager
def owned_dataset(out: Path, items: str = "scenes") -> Iterator[None]:
    """Hold ``out`` for one generator run: its lock (:class:`particlesplat.core.runlock.RunLock`, so a second
    ``synth`` into the folder ends in one line instead of deleting this one's scene in progress), and SIGTERM
    handled as Ctrl-C is (finished scenes kept, the worker pool stopped with the command: :func:`run_tasks`).
    ``items`` names what the folder holds in the line an interruption prints."""
    lock = RunLock(out).acquire()
    previous = None
    kept = f"finished {items} are kept in {out}; run the same command again to resume"
    if threading.current_thread() is threading.main_thread():  # the CLI's stop handler, saying what was kept
        previous = signal.signal(signal.SIGTERM, stop_signal_handler(kept))
    try:
        yield
    except KeyboardInterrupt as e:
        if isinstance(e, Interrupted):
            raise
        raise Interrupted(kept) from None
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        lock.release()


def _start_worker(init_worker: Callable[[], None]) -> None:
    """A pool worker: the default SIGTERM (the pool stops its workers with it) and SIGINT ignored (the parent
    stops the pool on Ctrl-C; a worker's own KeyboardInterrupt would only print a traceback), then ``init_worker``."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    init_worker()


def check_existing_generator(out: Path, generator: str) -> None:
    """UserError when scene folders already under ``out`` were written by a generator of another family, or by none
    this program knows (a robot dataset folder without its ``synth.json`` given to the tabletop generator would mix
    families)."""
    from particlesplat.data.families import family_of, family_of_generator
    from particlesplat.data.scene_meta import SCENE_META, read_scene_json

    want = family_of_generator(generator)
    for split in SPLITS:
        for scene in sorted((out / split).glob("scene_*"))[:1] if (out / split).is_dir() else []:
            meta = read_scene_json(scene / SCENE_META) if (scene / SCENE_META).is_file() else None
            have = family_of(meta, str(scene / SCENE_META))
            if have != want:
                recorded = meta.get("generator") if isinstance(meta, dict) else None
                raise UserError(
                    f"{scene / SCENE_META}: key 'generator' is {str(recorded)[:80]!r} but this run uses {generator!r}; "
                    "a dataset holds one family: use another output folder"
                )


def check_manifest(out: Path, want: dict) -> None:
    """Record the settings ``want`` of a dataset folder ``out`` in its ``synth.json`` (any generator); refuse
    to resume a folder made with other settings, or one whose scenes another generator wrote."""
    path = out / MANIFEST
    if path.exists():
        from particlesplat.data.scene_meta import read_scene_json

        have = read_scene_json(path)
        if not isinstance(have, dict):
            raise UserError(f"{path}: expected a JSON object, got {type(have).__name__}")
        for key, value in want.items():
            if have.get(key) != value:
                raise UserError(
                    f"{path}: key '{key}' is {have.get(key)!r} but this run uses {value!r}; "
                    "use another output folder or the same settings to resume"
                )
        return
    check_existing_generator(out, str(want.get("generator")))
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "w") as f:
        json.dump(want, f, indent=1)


def check_settings(out: Path, counts: dict[str, int], seed: int, res: int, workers: int) -> None:
    """OptionError naming the option for settings no generator can use (every family checks these)."""
    if seed < 0:
        raise OptionError(f"--seed must be >= 0, got {seed}")
    if not 8 <= res <= MAX_RES:
        raise OptionError(f"--res must be in [8, {MAX_RES}] (the largest image a scene may hold), got {res}")
    check_memory(
        SYNTH_BYTES_PER_PIXEL * res * res * max(workers, 1),
        f"--res {res} with --workers {workers}: {max(workers, 1)} scene(s) of {res}x{res} at a time",
    )
    if any(n < 0 for n in counts.values()):
        raise OptionError(f"scene counts must be >= 0, got {counts}")
    if out.exists() and not out.is_dir():
        raise OptionError(f"{out}: exists and is not a folder")


def missing_scenes(out: Path, counts: dict[str, int]) -> list[tuple[str, int]]:
    """(split, index) of every scene not yet written under ``out``; an interrupted scene's temporary folder is
    removed first."""
    todo = []
    for split in SPLITS:
        if (out / split).is_dir():
            for p in (out / split).glob(".scene_*.tmp"):
                shutil.rmtree(p, ignore_errors=True)
        todo += [(split, i) for i in range(counts.get(split, 0)) if not (out / split / scene_name(i)).is_dir()]
    return todo


def run_tasks(
    tasks: list, work: Callable[[Any], T], init_worker: Callable[[], None], workers: int, bar: tqdm
) -> list[T]:
    """``work(task)`` for every task, in ``workers`` processes (forked: no re-import; each runs ``init_worker``
    first) or in this one; the bar advances per task and is closed at the end. Returns the results as they come."""
    out: list[T] = []
    try:
        if workers <= 1 or len(tasks) <= 1:
            init_worker()
            for task in tasks:
                out.append(work(task))
                bar.update(1)
        else:
            method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
            start = functools.partial(_start_worker, init_worker)
            with mp.get_context(method).Pool(workers, initializer=start) as pool:
                for result in pool.imap_unordered(work, tasks):
                    out.append(result)
                    bar.update(1)
    finally:
        bar.close()
    return out


def generate(
    out: Path, counts: dict[str, int], seed: int, res: int = 128, workers: int = 2, progress: bool = True
) -> list[float]:
    """Write ``counts[split]`` scenes per split under ``out``; skip scenes that already exist.

    Returns the seconds each newly written scene took (worker wall time).
    """
    check_settings(out, counts, seed, res, workers)
    with owned_dataset(out):
        check_manifest(
            out, {"generator": "particlesplat.data.synth", "format_version": FORMAT_VERSION, "seed": seed, "res": res}
        )
        tasks = [(split, index, seed, res, str(out)) for split, index in missing_scenes(out, counts)]
        total = sum(counts.values())
        bar = tqdm(total=total, initial=total - len(tasks), desc="synth", unit="scene", disable=not progress)
        return run_tasks(tasks, _work, _init_worker, workers, bar)


def generate_family(out: Path, counts: dict[str, int], seed: int, options: argparse.Namespace) -> list[float]:
    """The tabletop family's generator entry (:class:`particlesplat.data.families.Family`): :func:`generate` with
    ``synth``'s ``options`` (``res``, ``workers``); the family has no held-out split, so ``counts``'s is left out."""
    counts = {split: n for split, n in counts.items() if split != "heldout"}
    return generate(out, counts, seed, options.res, options.workers)
