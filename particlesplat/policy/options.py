"""What the policy commands' options accept, checked without loading MuJoCo or torch (``--help`` and a bad option
are answered first): the task names (:data:`.tasks.TASKS` holds the tasks, in this order) and the world's splits."""

from __future__ import annotations

from particlesplat.core.errors import OptionError

TASK_NAMES = ("place", "stack")
DEFAULT_TASK = "place"
SPLITS = ("train", "heldout")  # the held-out split: held-out object colours and one more distractor
MAX_EPISODES = 100_000


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
