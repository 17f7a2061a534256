"""Closed-loop evaluation of a learned policy: rollouts in freshly drawn episodes of a task, success from the
simulator's state.

Rollout ``i`` is episode ``i`` of the evaluation seed (:func:`.tasks.episode_rng`), so every input is judged on
the same episodes, and a rollout is reproducible from its seed. A rollout ends once the task has succeeded (as
RLBench ends an episode) or after :data:`MAX_POLICY_DECISIONS` keyposes. Views are rendered only for the inputs
that read them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from .control import Keypose
from .features import Step, keypose_from_action, live_step
from .head import KeyposePolicy
from .learn import make_batch
from .rollout import Decider, Observation, run_episode
from .tasks import TASKS, build_task_world, episode_rng
from .world import TaskWorld

MAX_POLICY_DECISIONS = 10  # a clean expert episode takes 6


@dataclass
class EvalResult:
    """Per rollout: ``success``, ``decisions`` taken, ``wall_seconds`` and ``decision_seconds`` (the mean of its
    decisions': render the views, encode, act; the controller's motion not counted); and the settings."""

    task: str
    input: str
    seed: int
    split: str
    success: list[bool] = field(default_factory=list)
    decisions: list[int] = field(default_factory=list)
    wall_seconds: list[float] = field(default_factory=list)
    decision_seconds: list[float] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.success)) if self.success else 0.0

    @property
    def success_interval(self) -> tuple[float, float]:
        """The 95 % Wilson score interval (fractions) of the policy's true success rate on the task's episodes,
        from these rollouts."""
        return wilson_interval(sum(self.success), len(self.success))

    def to_json(self) -> dict:
        return {
            "task": self.task,
            "input": self.input,
            "seed": self.seed,
            "split": self.split,
            "rollouts": len(self.success),
            "success_rate": self.success_rate,
            "success_interval_95": [round(x, 4) for x in self.success_interval],
            "success": self.success,
            "decisions": self.decisions,
            "wall_seconds": [round(s, 3) for s in self.wall_seconds],
            "decision_seconds": [round(s, 4) for s in self.decision_seconds],
        }


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson's score interval of a binomial proportion (95 % at the default ``z``): the success rates ``p`` whose
    normal test ``|successes / trials - p| <= z sqrt(p (1 - p) / trials)`` passes. ``(0, 1)`` for no trials."""
    if trials <= 0:
        return 0.0, 1.0
    phat = successes / trials
    z2 = z * z / trials
    centre = (phat + z2 / 2) / (1 + z2)
    half = z * np.sqrt(phat * (1 - phat) / trials + z2 / trials / 4) / (1 + z2)
    return max(0.0, float(centre - half)), min(1.0, float(centre + half))


def policy_decider(model: KeyposePolicy, kind: str, particle_rows: Callable[[Step], tuple] | None = None) -> Decider:
    """A decider that asks ``model`` (input ``kind``) for the next keypose from what the step shows."""

    def decide(world: TaskWorld, obs: Observation) -> Keypose | None:
        step = live_step(world, obs)
        rows = [particle_rows(step)] if particle_rows is not None else None
        with torch.no_grad():
            action = model(make_batch(kind, [step], rows))[0].numpy()
        return keypose_from_action(action)

    return decide


def evaluate(
    task: str,
    kind: str,
    model: KeyposePolicy,
    rollouts: int,
    seed: int,
    split: str = "train",
    particle_rows: Callable[[Step], tuple] | None = None,
    progress: Callable[[int, bool], None] | None = None,
) -> EvalResult:
    """Run ``rollouts`` episodes (0..rollouts-1 of ``seed``) of ``task`` with the policy; their successes."""
    spec = TASKS[task]
    result = EvalResult(task, kind, seed, split)
    render = kind in ("images", "particles")
    for i in range(rollouts):
        start = time.perf_counter()
        world = build_task_world(episode_rng(seed, task, split, i), spec, split)
        episode = run_episode(
            world,
            spec,
            policy_decider(model, kind, particle_rows),
            render=render,
            max_decisions=MAX_POLICY_DECISIONS,
            stop_on_success=True,
        )
        result.success.append(bool(episode.success))
        result.decisions.append(len(episode.steps))
        result.wall_seconds.append(time.perf_counter() - start)
        result.decision_seconds.append(float(np.mean(episode.decision_seconds)) if episode.decision_seconds else 0.0)
        if progress is not None:
            progress(i, bool(episode.success))
    return result
