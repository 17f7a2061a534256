"""What the policy commands' options accept, checked without loading MuJoCo or torch (``--help`` and a bad option
are answered first): the task names (:data:`.tasks.TASKS` holds the tasks, in this order) and the world's splits."""

from __future__ import annotations

from particlesplat.core.errors import OptionError

TASK_NAMES = ("place", "stack")
DEFAULT_TASK = "place"
SPLITS = ("train", "heldout")  # the held-out split: held-out object colours and one more distractor
MAX_EPISODES = 100_000
ROBOT_ALONE = "robot"  # the input of the robot's own state alone, the floor (an input's name, not the family's)
INPUT_NAMES = ("particles", "images", "state", ROBOT_ALONE)  # what --input takes (the head's token sources)
MAX_STEPS, MAX_BATCH, MAX_ROLLOUTS = 10_000_000, 4096, 100_000
TRAIN_STEPS = 6000  # the training budget of every input: at 2,000 the particles policy had not fit its own data


def check_collect_options(task: str, episodes: int, seed: int, split: str) -> None:
    """OptionError naming the option of ``policy collect`` that no run can use."""
    if task not in TASK_NAMES:
        raise OptionError(f"--task must be one of {', '.join(TASK_NAMES)}, got {task[:80]!r}")
    if not 1 <= episodes <= MAX_EPISODES:
        raise OptionError(f"--episodes must be in [1, {MAX_EPISODES}], got {episodes}")
    if seed < 0:
        raise OptionError(f"--seed must be >= 0, got {seed}")
    if split not in SPLITS:
        raise OptionError(f"--split must be one of {', '.join(SPLITS)}, got {split[:80]!r}")


def check_train_options(episodes: int | None, steps: int, batch: int, seed: int, lr: float) -> None:
    """OptionError naming the option of ``policy train`` that no run can use."""
    if episodes is not None and not 1 <= episodes <= MAX_EPISODES:
        raise OptionError(f"--episodes must be in [1, {MAX_EPISODES}], got {episodes}")
    if not 1 <= steps <= MAX_STEPS:
        raise OptionError(f"--steps must be in [1, {MAX_STEPS}], got {steps}")
    if not 1 <= batch <= MAX_BATCH:
        raise OptionError(f"--batch must be in [1, {MAX_BATCH}], got {batch}")
    if seed < 0:
        raise OptionError(f"--seed must be >= 0, got {seed}")
    if not 0.0 < lr <= 1.0:
        raise OptionError(f"--lr must be in (0, 1], got {lr}")


def check_eval_options(rollouts: int, seed: int) -> None:
    """OptionError naming the option of ``policy eval`` that no run can use."""
    if not 1 <= rollouts <= MAX_ROLLOUTS:
        raise OptionError(f"--rollouts must be in [1, {MAX_ROLLOUTS}], got {rollouts}")
    if seed < 0:
        raise OptionError(f"--seed must be >= 0, got {seed}")
