"""The policy tasks: what objects a task's episode holds, where they start, and when it has succeeded.

Two tasks, each with 1-3 distractors drawn as the wide robot world draws its objects (robosuite's objects and
MuJoCo primitives in the split's colours):

- ``place``: pick the target (a box or an upright cylinder the Panda's fingers span) and place it on the goal, a
  dark disc on the table (:data:`GOAL_RADIUS`). Success: the target rests on the table with its centre over the
  disc, out of the gripper.
- ``stack``: pick the target (a small box) and stack it on the base (a wider, flat box). Success: the target rests
  on the base's top face with its centre over it, the base on the table, the target out of the gripper.

Success is read from the simulator's state (:func:`placed`, :func:`stacked`): the objects' boxes (from their
geoms at the current state), their velocities and the gripper's contacts. An episode draws from its own RNG
(:func:`episode_rng`), so it depends on nothing but the seed, the task, the split and its index.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from particlesplat.data.families.robot_compose import Marker, ObjectSpec
from particlesplat.data.families.robot_wide import Ranges, draw_primitive, object_drawer

from .options import SPLITS, TASK_NAMES
from .world import (
    HELDOUT_EXTRA_DISTRACTORS,
    MAX_WORLD_TRIES,
    TaskWorld,
    build_world,
    draw_setup,
    footprints,
    place_discs,
    split_ranges,
)

GOAL_RADIUS = 0.05  # metres: the goal disc, and how far from its centre the target's centre may rest
GOAL_RGBA = (0.04, 0.04, 0.04, 1.0)  # darker than any object (values >= 0.35) or surface (>= 0.5) is drawn
MIN_TRAVEL = 0.08  # metres: the target starts at least this much farther from the goal than touching it
ON_TABLE = 0.01  # metres: a box's bottom within this of z = 0 rests on the table
ON_TOP = 0.01  # metres: the target's bottom within this of the base's top rests on it
AT_REST = 0.05  # m/s and rad/s: an object slower than this has come to rest
# graspable targets (the Panda's fingers open 0.08 m): half sizes, metres
PLACE_BOX_NARROW, PLACE_BOX_WIDE, PLACE_BOX_HEIGHT = (0.018, 0.03), (0.018, 0.045), (0.02, 0.04)
PLACE_CYLINDER_RADIUS, PLACE_CYLINDER_HEIGHT = (0.018, 0.03), (0.025, 0.05)
STACK_TOP_HALF, STACK_TOP_HEIGHT = (0.018, 0.028), (0.018, 0.03)
STACK_BASE_HALF, STACK_BASE_HEIGHT = (0.038, 0.05), (0.02, 0.035)
DISTRACTORS = {"place": (1, 3), "stack": (1, 3)}
TASK_IDS = {name: i for i, name in enumerate(TASK_NAMES)}  # an episode's RNG is seeded by its task's id


@dataclass(frozen=True)
class Task:
    """One task.

    Attributes:
        name: what ``--task`` says.
        summary: one line for ``--help`` and the docs.
        draw_objects: (rng, the split's ranges, distractors) -> the objects at the origin and their roles, in
            the order MuJoCo numbers them: "target", then "base" (stack), then "distractor"s.
        goal: the task has a goal disc on the table.
        success: the episode's success, from the simulator's state of a world.
        place_point: (3,) where the target's bottom centre is to go, world metres, from the state of a world.
    """

    name: str
    summary: str
    draw_objects: Callable[[np.random.Generator, Ranges, int], tuple[list[ObjectSpec], list[str]]]
    goal: bool
    success: Callable[[TaskWorld], bool]
    place_point: Callable[[TaskWorld], np.ndarray]


def _uniform(rng: np.random.Generator, interval: tuple[float, float]) -> float:
    return float(rng.uniform(*interval))


def _box(rng: np.random.Generator, ranges: Ranges, half: tuple[float, float, float]) -> ObjectSpec:
    """A box of ``half`` sizes in the split's colours (and maybe a tinted texture), as the wide world draws one."""
    return replace(draw_primitive(rng, "box", ranges), half_size=half)


def graspable_target(rng: np.random.Generator, ranges: Ranges) -> ObjectSpec:
    """A box narrow enough across one side, or an upright cylinder, for the Panda's fingers."""
    if rng.uniform() < 0.5:
        narrow, wide, height = (_uniform(rng, r) for r in (PLACE_BOX_NARROW, PLACE_BOX_WIDE, PLACE_BOX_HEIGHT))
        return _box(rng, ranges, (narrow, wide, height) if rng.uniform() < 0.5 else (wide, narrow, height))
    r = _uniform(rng, PLACE_CYLINDER_RADIUS)
    return replace(draw_primitive(rng, "cylinder", ranges), half_size=(r, r, _uniform(rng, PLACE_CYLINDER_HEIGHT)))


def distractors(rng: np.random.Generator, ranges: Ranges, count: int, used: set[str]) -> list[ObjectSpec]:
    """``count`` objects drawn as the wide world draws its objects (no robosuite object twice)."""
    draw = object_drawer(ranges)
    out = []
    for _ in range(count):
        spec = draw(rng, used)
        used.add(spec.kind)
        out.append(spec)
    return out


def _place_objects(rng: np.random.Generator, ranges: Ranges, extra: int) -> tuple[list[ObjectSpec], list[str]]:
    target = graspable_target(rng, ranges)
    lo, hi = DISTRACTORS["place"]
    others = distractors(rng, ranges, int(rng.integers(lo, hi + 1)) + extra, {target.kind})
    return [target, *others], ["target"] + ["distractor"] * len(others)


def _stack_objects(rng: np.random.Generator, ranges: Ranges, extra: int) -> tuple[list[ObjectSpec], list[str]]:
    top = _box(
        rng, ranges, (_uniform(rng, STACK_TOP_HALF), _uniform(rng, STACK_TOP_HALF), _uniform(rng, STACK_TOP_HEIGHT))
    )
    base = _box(
        rng, ranges, (_uniform(rng, STACK_BASE_HALF), _uniform(rng, STACK_BASE_HALF), _uniform(rng, STACK_BASE_HEIGHT))
    )
    lo, hi = DISTRACTORS["stack"]
    others = distractors(rng, ranges, int(rng.integers(lo, hi + 1)) + extra, {"box"})
    return [top, base, *others], ["target", "base"] + ["distractor"] * len(others)


def _released_at_rest(world: TaskWorld, k: int) -> bool:
    return not world.touching_gripper(k) and float(world.speeds()[k]) < AT_REST


def placed(world: TaskWorld) -> bool:
    """``place``'s success: the target's bottom within :data:`ON_TABLE` of the table, its centre within the goal
    disc's radius of the goal's centre (in x, y), out of the gripper and at rest."""
    if world.goal is None:
        raise ValueError("the place task's world has no goal")
    k = world.index("target")
    lo, hi = world.box(k)
    centre = (lo + hi) / 2.0
    on_goal = float(np.hypot(*(centre[:2] - world.goal[:2]))) <= world.goal_radius
    return bool(abs(lo[2]) <= ON_TABLE and on_goal and _released_at_rest(world, k))


def stacked(world: TaskWorld) -> bool:
    """``stack``'s success: the target's bottom within :data:`ON_TOP` of the base's top, the target's centre over
    the base's box (in x, y), the base on the table, the target out of the gripper and both at rest."""
    a, b = world.index("target"), world.index("base")
    lo_a, hi_a = world.box(a)
    lo_b, hi_b = world.box(b)
    centre = (lo_a + hi_a) / 2.0
    over = bool(np.all(centre[:2] >= lo_b[:2]) and np.all(centre[:2] <= hi_b[:2]))
    on_top = abs(float(lo_a[2] - hi_b[2])) <= ON_TOP
    base_down = abs(float(lo_b[2])) <= ON_TABLE and float(world.speeds()[b]) < AT_REST
    return bool(over and on_top and base_down and _released_at_rest(world, a))


def _goal_point(world: TaskWorld) -> np.ndarray:
    if world.goal is None:
        raise ValueError("the place task's world has no goal")
    return np.array([world.goal[0], world.goal[1], 0.0])


def _base_top(world: TaskWorld) -> np.ndarray:
    lo, hi = world.box(world.index("base"))
    return np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, hi[2]])


TASKS: dict[str, Task] = {
    t.name: t
    for t in (
        Task(
            "place",
            "pick the target object and place it on the dark goal disc, among 1-3 distractors",
            _place_objects,
            True,
            placed,
            _goal_point,
        ),
        Task(
            "stack",
            "pick the small box and stack it on the wider box, among 1-3 distractors",
            _stack_objects,
            False,
            stacked,
            _base_top,
        ),
    )
}


def episode_rng(seed: int, task: str, split: str, index: int) -> np.random.Generator:
    """Episode ``index``'s RNG: independent of every other episode, the worker count and resuming."""
    return np.random.default_rng(np.random.SeedSequence([seed, TASK_IDS[task], SPLITS.index(split), index]))


def build_task_world(rng: np.random.Generator, task: Task, split: str = "train", assets=None) -> TaskWorld:
    """Draw and settle one episode's world: the look (lights, surfaces), the task's objects (the held-out split:
    held-out colours and one more distractor) and, for a task with a goal, the goal disc, all within the arm's
    reach and apart; drawn again until the objects settle clear of each other."""
    ranges = split_ranges(split)
    extra = HELDOUT_EXTRA_DISTRACTORS if split == "heldout" else 0
    setup = draw_setup(rng)
    from particlesplat.data.families.robot_assets import assets_dir, import_mujoco

    mujoco, assets = import_mujoco(), assets_dir(assets)
    for _ in range(MAX_WORLD_TRIES):
        specs, roles = task.draw_objects(rng, ranges, extra)
        radii = [f[0] for f in footprints(mujoco, assets, specs)]
        apart = None
        if task.goal:  # the goal is disc 0, the target disc 1: they start MIN_TRAVEL farther apart
            radii = [GOAL_RADIUS, *radii]
            apart = [[0.0] * len(radii) for _ in radii]
            apart[0][1] = apart[1][0] = MIN_TRAVEL
        centres = place_discs(rng, radii, apart)
        if centres is None:
            continue
        goal, marker = None, None
        if task.goal:
            gx, gy = (float(v) for v in centres[0])
            goal, marker = np.array([gx, gy, 0.0]), Marker("goal", gx, gy, GOAL_RADIUS, GOAL_RGBA)
            centres = centres[1:]
        placed_specs = [
            replace(s, x=float(c[0]), y=float(c[1]), yaw=float(rng.uniform(-math.pi, math.pi)))
            for s, c in zip(specs, centres, strict=True)
        ]
        world = build_world(rng, placed_specs, roles, goal, marker, setup, split, assets)
        if world is not None:
            return world
    raise RuntimeError(f"no {task.name} layout settled in {MAX_WORLD_TRIES} tries")
