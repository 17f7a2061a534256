"""Behaviour cloning of the expert's keyposes: batches of decisions for one input, the training loop, and the
policy file.

A training sample is one decision of a successful demonstration: what the input sees then (:mod:`.features`)
and the keypose the expert took. Each batch's colours are turned by one random hue rotation (:func:`turn_hues`):
which object is the target is told by colours matching, never by which colour, and a few hundred decisions
show only a few hundred colours. The loss is EC-Diffuser's L1 on the action, the position's term weighted by
:data:`POSITION_WEIGHT` (centimetres matter as much as the rotation's unit columns). Every input trains with the
same sizes, steps, batch and learning-rate schedule; only the tokens differ.

A policy file (``torch.save``, written atomically) holds the weights, the input, the task, the training settings
and what it was trained on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from particlesplat.core.errors import UserError

from .features import Step, image_features, image_points, keypose_target, object_features, robot_features
from .head import INPUTS, KeyposePolicy, SetTokens, token_source
from .options import ROBOT_ALONE, TRAIN_STEPS

POSITION_WEIGHT = 10.0
POLICY_FORMAT = "particlesplat-keypose-policy"
POLICY_VERSION = 2  # 2: the position is pointed at (head.KeyposePolicy)


class PolicyFileError(UserError):
    """A policy file that cannot be used; the message names it and the key."""


@dataclass(frozen=True)
class TrainSettings:
    """The training budget, the same for every input: ``steps`` of ``batch`` decisions, AdamW at ``lr`` with a
    cosine to zero and ``weight_decay``, from ``seed``."""

    steps: int = TRAIN_STEPS
    batch: int = 32
    lr: float = 3e-4
    weight_decay: float = 1e-4
    seed: int = 0


# A step's particle rows: (P, F) features, (P,) view index, (P,) active; given by the particle input's encoder
ParticleRows = Callable[[Step], tuple[np.ndarray, np.ndarray, np.ndarray]]


def _pad(rows: Sequence[np.ndarray], dims: int) -> tuple[np.ndarray, np.ndarray]:
    n = max((len(r) for r in rows), default=0)
    out = np.zeros((len(rows), max(n, 1), dims), np.float32)
    mask = np.zeros((len(rows), max(n, 1)), bool)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
        mask[i, : len(r)] = True
    return out, mask


def make_batch(
    kind: str,
    steps: Sequence[Step],
    particles: Sequence[tuple] | None = None,
    points: Sequence[np.ndarray] | None = None,
) -> dict[str, torch.Tensor]:
    """The tensors input ``kind`` reads for ``steps`` (``particles``: each step's particle rows, for
    ``particles``; ``points``: each step's :func:`.features.image_points` when already computed, for
    ``images``)."""
    batch = {"robot": torch.from_numpy(np.stack([robot_features(s) for s in steps]))}
    if kind == "state":
        rows = [object_features(s) for s in steps]
        objects, mask = _pad(rows, rows[0].shape[1])
        batch["objects"], batch["objects_mask"] = torch.from_numpy(objects), torch.from_numpy(mask)
        batch["objects_mask"][:, 0] |= ~batch["objects_mask"].any(1)  # an empty set keeps one (zero) row
    elif kind == "images":
        batch["images"] = torch.from_numpy(np.stack([image_features(s) for s in steps]))
        cells = [image_points(s) for s in steps] if points is None else points
        batch["images_points"] = torch.from_numpy(np.stack(cells))
    elif kind == "particles":
        if particles is None:
            raise ValueError("the particles input needs each step's particle rows")
        feats, mask = _pad([p[0] for p in particles], particles[0][0].shape[1])
        views = np.zeros(mask.shape, np.int64)
        for i, p in enumerate(particles):
            views[i, : len(p[1])] = p[1]
            mask[i, : len(p[2])] &= p[2]
        mask[:, 0] |= ~mask.any(1)
        batch["particles"] = torch.from_numpy(feats)
        batch["particles_view"] = torch.from_numpy(views)
        batch["particles_mask"] = torch.from_numpy(mask)
    elif kind != ROBOT_ALONE:
        raise ValueError(f"unknown input {kind!r}")
    return batch


def demo_samples(folder: Path, task: str, episodes: int | None = None) -> tuple[list[tuple[Step, np.ndarray]], list]:
    """The decisions of the first ``episodes`` successful demonstrations in ``folder`` (all with None), as
    (step, keypose (8,)), and those episodes' ``(index, decision)`` per sample (for caches keyed by decision).

    Raises:
        UserError: the folder holds another task's demonstrations, or fewer successful ones than ``episodes``.
    """
    from .episodes import read_episodes
    from .features import episode_steps

    manifest, found = read_episodes(folder, successful_only=True)
    if manifest.get("task") != task:
        raise UserError(f"{folder}: its demonstrations are of task {manifest.get('task')!r}, not {task!r} (--task)")
    if episodes is not None:
        if len(found) < episodes:
            raise UserError(f"{folder}: holds {len(found)} successful demonstrations, fewer than --episodes {episodes}")
        found = found[:episodes]
    samples, keys = [], []
    for ep in found:
        for t, (step, keypose) in enumerate(episode_steps(ep)):
            samples.append((step, keypose))
            keys.append((int(ep.meta["index"]), t))
    return samples, keys


def hue_turn(angle: float) -> torch.Tensor:
    """(3, 3) the rotation of RGB by ``angle`` radians about the grey axis (greys and colour distances kept)."""
    axis = torch.full((3,), 1.0 / math.sqrt(3.0))
    K = torch.tensor([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return torch.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def turn_hues(kind: str, batch: dict[str, torch.Tensor], angles: np.ndarray) -> None:
    """Turn every colour sample ``i`` of ``batch`` carries by ``angles[i]`` radians in place (the same turn for all
    of a sample's objects, particles or pixels; views' RGB clipped to [0, 1])."""
    from .features import OBJECT_COLOUR
    from .particles import PARTICLE_COLOUR

    turns = torch.stack([hue_turn(float(a)) for a in angles])  # (B, 3, 3)
    if kind == "state":
        rows = batch["objects"][..., OBJECT_COLOUR]
        batch["objects"][..., OBJECT_COLOUR] = torch.einsum("bij,bnj->bni", turns, rows)
    elif kind == "particles":
        rows = batch["particles"][..., PARTICLE_COLOUR]
        batch["particles"][..., PARTICLE_COLOUR] = torch.einsum("bij,bnj->bni", turns, rows)
    elif kind == "images":
        rgb = batch["images"][:, :, :3]
        batch["images"][:, :, :3] = torch.einsum("bij,bvjhw->bvihw", turns, rgb).clamp(0.0, 1.0)


def action_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L1 on the action, the position's three numbers weighted by :data:`POSITION_WEIGHT`."""
    err = (pred - target).abs()
    return (POSITION_WEIGHT * err[:, :3].sum(1) + err[:, 3:].sum(1)).mean()


@dataclass
class TrainLog:
    """Per logged step: the step, the batch loss and the wall seconds so far."""

    steps: list[int]
    losses: list[float]
    seconds: list[float]


def train(
    kind: str,
    samples: Sequence[tuple[Step, np.ndarray]],
    settings: TrainSettings,
    particles: Sequence[tuple] | None = None,
    particle_dims: int = 0,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[KeyposePolicy, TrainLog]:
    """Train a policy of input ``kind`` on ``samples`` (step, keypose (8,)); ``particles`` holds each sample's
    particle rows for the particles input. Deterministic for ``settings.seed`` on one machine."""
    if kind not in INPUTS:
        raise ValueError(f"unknown input {kind!r}")
    if not samples:
        raise UserError("no successful demonstration to learn from")
    torch.manual_seed(settings.seed)
    rng = np.random.default_rng(settings.seed)
    model = KeyposePolicy(token_source(kind, particle_dims) if kind == "particles" else token_source(kind))
    opt = torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    targets = np.stack([keypose_target(k) for _, k in samples])
    points = [image_points(s) for s, _ in samples] if kind == "images" else None  # once, not every batch
    log = TrainLog([], [], [])
    start = time.perf_counter()
    model.train()
    from particlesplat.core.threads import ThreadGovernor

    governor = ThreadGovernor(torch.get_num_threads())  # threads spinning on busy cores made a step 10x slower
    for step in range(settings.steps):
        if step % 20 == 0:
            governor.update()
        lr = settings.lr * 0.5 * (1.0 + math.cos(math.pi * step / settings.steps))
        for g in opt.param_groups:
            g["lr"] = lr
        idx = rng.choice(len(samples), size=min(settings.batch, len(samples)), replace=len(samples) < settings.batch)
        batch = make_batch(
            kind,
            [samples[i][0] for i in idx],
            None if particles is None else [particles[i] for i in idx],
            None if points is None else [points[i] for i in idx],
        )
        turn_hues(kind, batch, rng.uniform(0.0, 2.0 * math.pi, len(idx)))
        loss = action_loss(model(batch), torch.from_numpy(targets[idx]))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if step % 50 == 0 or step == settings.steps - 1:
            log.steps.append(step)
            log.losses.append(float(loss.detach()))
            log.seconds.append(time.perf_counter() - start)
            if progress is not None:
                progress(step, float(loss.detach()))
    model.eval()
    return model, log


def save_policy(path: Path, model: KeyposePolicy, kind: str, task: str, settings: TrainSettings, info: dict) -> None:
    """Write the policy file atomically."""
    from particlesplat.core.atomic import atomic_path

    particle_dims = 0
    if isinstance(model.source, SetTokens) and kind == "particles":
        first = model.source.embed[0]
        particle_dims = first.in_features if isinstance(first, torch.nn.Linear) else 0
    payload = {
        "format": POLICY_FORMAT,
        "format_version": POLICY_VERSION,
        "input": kind,
        "task": task,
        "particle_dims": int(particle_dims),
        "settings": asdict(settings),
        "info": info,
        "state_dict": model.state_dict(),
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_policy(path: Path) -> tuple[KeyposePolicy, dict]:
    """The policy in ``path`` and its file's other keys; PolicyFileError names the file and what is wrong."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as e:  # noqa: BLE001 - torch reports a bad file as many types
        raise PolicyFileError(f"{path}: not a policy file this program reads ({type(e).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != POLICY_FORMAT:
        raise PolicyFileError(f"{path}: key 'format': not a {POLICY_FORMAT} file")
    if payload.get("format_version") != POLICY_VERSION:
        raise PolicyFileError(f"{path}: key 'format_version': this program reads {POLICY_VERSION}")
    kind = payload.get("input")
    if kind not in INPUTS:
        raise PolicyFileError(f"{path}: key 'input': one of {', '.join(INPUTS)} expected")
    source = token_source(kind, int(payload.get("particle_dims", 0))) if kind == "particles" else token_source(kind)
    model = KeyposePolicy(source)
    try:
        model.load_state_dict(payload["state_dict"])
    except (KeyError, RuntimeError) as e:
        raise PolicyFileError(f"{path}: key 'state_dict': {' '.join(str(e).split())[:160]}") from None
    model.eval()
    return model, {k: v for k, v in payload.items() if k != "state_dict"}
