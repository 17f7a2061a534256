"""What ``policy train`` and ``policy eval`` do, over library calls: train a policy of one input on a folder of
demonstrations and write it; evaluate a policy file in closed loop and summarise it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from particlesplat.core.errors import UserError

from .evaluate import EvalResult, evaluate
from .learn import TrainLog, TrainSettings, demo_samples, load_policy, save_policy, train


def particle_cache(folder: Path | None, index: int, decision: int) -> Path | None:
    """Where decision ``decision`` of episode ``index`` keeps its particle arrays under ``folder`` (None: none)."""
    return None if folder is None else folder / f"episode_{index:05d}" / f"decision_{decision:02d}.npz"


def train_run(
    task: str,
    kind: str,
    demos: Path,
    out: Path,
    settings: TrainSettings,
    episodes: int | None = None,
    model: str | None = None,
    particles: Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> TrainLog:
    """Train a ``kind`` policy on the successful demonstrations of ``task`` in ``demos`` (the first ``episodes``)
    and write it to ``out``. The particles input encodes every decision with ``model`` (None: the shipped robot
    model), keeping the arrays under ``particles`` when given (read back on the next run)."""
    samples, keys = demo_samples(demos, task, episodes)
    rows, dims = None, 0
    info: dict = {"demos": str(demos), "episodes": len({k[0] for k in keys}), "decisions": len(samples)}
    if kind == "particles":
        from .particles import DecisionEncoder

        encoder = DecisionEncoder(model)
        shipped = model is None
        rows = []
        for n, ((step, _), (index, decision)) in enumerate(zip(samples, keys, strict=True)):
            rows.append(encoder.rows(step, particle_cache(particles, index, decision)))
            if progress is not None:
                progress("encode", n + 1, len(samples))
        dims = encoder.dims
        # None: the shipped robot model, wherever this copy of the program keeps it
        info["encoder"] = {"checkpoint": None if shipped else encoder.checkpoint, "sha256": encoder.sha256}

    def report(step: int, loss: float) -> None:
        if progress is not None:
            progress("train", step + 1, settings.steps)

    policy, log = train(kind, samples, settings, rows, dims, report)
    info["final_loss"] = log.losses[-1]
    info["train_seconds"] = log.seconds[-1]
    save_policy(out, policy, kind, task, settings, info)
    return log


def eval_run(
    path: Path,
    task: str | None,
    rollouts: int,
    seed: int,
    split: str,
    model: str | None = None,
    progress: Callable[[int, bool], None] | None = None,
    started: Callable[[], None] | None = None,
) -> EvalResult:
    """Evaluate the policy in ``path`` on ``rollouts`` episodes of ``task`` (None: the policy's own) drawn from
    ``seed`` and ``split``; the particles input encodes with ``model`` (None: the encoder it was trained with).
    ``started`` is called once the policy and its encoder are loaded and checked, before the first rollout."""
    policy, meta = load_policy(path)
    kind = str(meta["input"])
    task = task or str(meta["task"])
    if task != meta["task"]:
        raise UserError(f"{path}: a policy of task {meta['task']!r}, asked to run task {task!r} (--task)")
    rows = None
    if kind == "particles":
        from .particles import DecisionEncoder

        encoder = DecisionEncoder(model or trained_encoder(path, meta))
        rows = encoder.rows
    if started is not None:
        started()
    return evaluate(task, kind, policy, rollouts, seed, split, rows, progress)


def trained_encoder(path: Path, meta: dict) -> str | None:
    """The model that encoded a particles policy's demonstrations (None: the shipped robot model), checked against
    its recorded SHA-256. A relative path is in the policy file's folder; a path that is not on this machine is the
    shipped model when the hashes match; a model that is not the one the policy learnt from (the shipped model
    replaced since, or the file at the recorded path changed) is a UserError naming ``path`` and the key, never a
    silent run on other particles."""
    from particlesplat.analysis.particle_arrays import file_sha256
    from particlesplat.data.families import get_family

    recorded = meta.get("info", {}).get("encoder", {})
    checkpoint, sha = recorded.get("checkpoint"), recorded.get("sha256")
    shipped = get_family("robot").shipped_model_path()
    if checkpoint is None:
        if sha is not None and sha != file_sha256(shipped):
            raise UserError(
                f"{path}: key 'info.encoder.sha256': the policy learnt from the particles of a robot model that is not "
                f"the shipped {shipped} any longer (SHA-256 {sha[:12]}...); give that model with --checkpoint, or "
                "train the policy again"
            )
        return None
    if not Path(str(checkpoint)).is_absolute():  # a model kept beside the policy (a shipped policy's own encoder)
        checkpoint = str(path.parent / str(checkpoint))
    if Path(str(checkpoint)).is_file():
        if sha is not None and sha != file_sha256(checkpoint):
            raise UserError(
                f"{path}: key 'info.encoder.sha256': {checkpoint} changed since the policy learnt from its particles "
                f"(SHA-256 {sha[:12]}...); give the model it learnt from with --checkpoint"
            )
        return str(checkpoint)
    if sha is not None and sha == file_sha256(shipped):
        return None
    raise UserError(
        f"{path}: key 'info.encoder.checkpoint': the model its particles came from, {checkpoint}, is not here "
        "(give it with --checkpoint)"
    )


def write_json(path: Path, data: dict) -> None:
    from particlesplat.core.atomic import atomic_write

    with atomic_write(path, "w") as f:
        json.dump(data, f, indent=1)
