"""The policy tasks: what objects a task's episode holds, where they start, and when it has succeeded.

Two tasks, each with 1-3 distractors drawn as the wide robot world draws its objects (robosuite's objects and
MuJoCo primitives in the split's colours). What to pick is seen, never told:

- ``place``: pick the target (a box or an upright cylinder the Panda's fingers span, in one plain colour) and
  place it on the goal, a low pad fixed on the table in the target's colour (:data:`GOAL_RADIUS`,
  :data:`GOAL_HEIGHT`: tall enough for the robot model's foreground evidence, 1.2 cm, to count it); the
  distractors' colours are at least :data:`MIN_HUE_GAP` away from it. Success: the target rests on the pad with
  its centre over it, out of the gripper.
- ``stack``: pick the target (a small box) and stack it on the base (a wider, flat box); no distractor is a box.
  Success: the target rests on the base's top face with its centre over it, the base on the table, the target
  out of the gripper.

Success is read from the simulator's state (:func:`placed`, :func:`stacked`): the objects' boxes (from their
geoms at the current state), their velocities and the gripper's contacts. An episode draws from its own RNG
(:func:`episode_rng`), so it depends on nothing but the seed, the task, the split and its index.
"""

from __future__ import annotations

import colorsys
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from particlesplat.data.families.robot_compose import Marker, ObjectSpec
from particlesplat.data.families.robot_wide import Ranges, draw_colour, draw_primitive, object_drawer

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

GOAL_RADIUS = 0.05  # metres: the goal pad, and how far from its centre the target's centre may rest
GOAL_HEIGHT = 0.02  # metres: the pad's top
MIN_HUE_GAP = 60.0  # degrees of hue between the target (and its pad) and any distractor primitive
TARGET_SATURATION, TARGET_VALUE = (0.6, 1.0), (0.5, 1.0)  # the target's plain colour (HSV)
MIN_TRAVEL = 0.08  # metres: the target starts at least this much farther from the goal than touching it
ON_TABLE = 0.01  # metres: a box's bottom within this of z = 0 rests on the table
ON_TOP = 0.01  # metres: the target's bottom within this of the top it is put on (the pad's, the base's)
MAX_DRAWS = 100  # draws of a distractor that must differ from the target
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
        goal: the task has a goal pad on the table.
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


def hue_of(rgba) -> float:
    """The hue of an (r, g, b, a) colour, degrees."""
    return colorsys.rgb_to_hsv(float(rgba[0]), float(rgba[1]), float(rgba[2]))[0] * 360.0


def hue_gap(a: float, b: float) -> float:
    """Degrees between two hues around the circle."""
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


def graspable_target(rng: np.random.Generator, ranges: Ranges) -> ObjectSpec:
    """A box narrow enough across one side, or an upright cylinder, for the Panda's fingers, in one plain colour
    of the split's hues (no texture: its colour is what marks it)."""
    if rng.uniform() < 0.5:
        narrow, wide, height = (_uniform(rng, r) for r in (PLACE_BOX_NARROW, PLACE_BOX_WIDE, PLACE_BOX_HEIGHT))
        half = (narrow, wide, height) if rng.uniform() < 0.5 else (wide, narrow, height)
        kind = "box"
    else:
        r = _uniform(rng, PLACE_CYLINDER_RADIUS)
        half, kind = (r, r, _uniform(rng, PLACE_CYLINDER_HEIGHT)), "cylinder"
    rgba = draw_colour(rng, ranges.hues, TARGET_SATURATION, TARGET_VALUE)
    return ObjectSpec(kind, 0.0, 0.0, 0.0, half, None, rgba)


def distractors(
    rng: np.random.Generator,
    ranges: Ranges,
    count: int,
    used: set[str],
    keep: Callable[[ObjectSpec], bool] = lambda spec: True,
) -> list[ObjectSpec]:
    """``count`` objects drawn as the wide world draws its objects (no robosuite object twice), each drawn again
    until ``keep`` accepts it (at most :data:`MAX_DRAWS` times)."""
    draw = object_drawer(ranges)
    out = []
    for _ in range(count):
        for _ in range(MAX_DRAWS):
            spec = draw(rng, used)
            if keep(spec):
                break
        else:
            raise RuntimeError("no distractor the task accepts")
        used.add(spec.kind)
        out.append(spec)
    return out


def _place_objects(rng: np.random.Generator, ranges: Ranges, extra: int) -> tuple[list[ObjectSpec], list[str]]:
    target = graspable_target(rng, ranges)
    hue = hue_of(target.rgba)
    lo, hi = DISTRACTORS["place"]

    def unlike(spec: ObjectSpec) -> bool:
        return spec.rgba is None or hue_gap(hue_of(spec.rgba), hue) >= MIN_HUE_GAP

    others = distractors(rng, ranges, int(rng.integers(lo, hi + 1)) + extra, set(), unlike)
    return [target, *others], ["target"] + ["distractor"] * len(others)


def _stack_objects(rng: np.random.Generator, ranges: Ranges, extra: int) -> tuple[list[ObjectSpec], list[str]]:
    top = _box(
        rng, ranges, (_uniform(rng, STACK_TOP_HALF), _uniform(rng, STACK_TOP_HALF), _uniform(rng, STACK_TOP_HEIGHT))
    )
    base = _box(
        rng, ranges, (_uniform(rng, STACK_BASE_HALF), _uniform(rng, STACK_BASE_HALF), _uniform(rng, STACK_BASE_HEIGHT))
    )
    lo, hi = DISTRACTORS["stack"]
    others = distractors(rng, ranges, int(rng.integers(lo, hi + 1)) + extra, set(), lambda s: s.kind != "box")
    return [top, base, *others], ["target", "base"] + ["distractor"] * len(others)


def _released_at_rest(world: TaskWorld, k: int) -> bool:
    return not world.touching_gripper(k) and float(world.speeds()[k]) < AT_REST


def placed(world: TaskWorld) -> bool:
    """``place``'s success: the target's bottom within :data:`ON_TOP` of the goal pad's top, its centre within the
    pad's radius of the pad's centre (in x, y), out of the gripper and at rest."""
    if world.goal is None:
        raise ValueError("the place task's world has no goal")
    k = world.index("target")
    lo, hi = world.box(k)
    centre = (lo + hi) / 2.0
    on_goal = float(np.hypot(*(centre[:2] - world.goal[:2]))) <= world.goal_radius
    return bool(abs(float(lo[2] - world.goal[2])) <= ON_TOP and on_goal and _released_at_rest(world, k))


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
    return np.array([world.goal[0], world.goal[1], world.goal[2]])


def _base_top(world: TaskWorld) -> np.ndarray:
    lo, hi = world.box(world.index("base"))
    return np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, hi[2]])


TASKS: dict[str, Task] = {
    t.name: t
    for t in (
        Task(
            "place",
            "pick the object in the goal pad's colour and place it on the pad, among 1-3 distractors",
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
    held-out colours and one more distractor) and, for a task with a goal, the goal pad, all within the arm's
    reach and apart (the goal pad in the target's colour); drawn again until the objects settle clear of each
    other."""
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
            goal = np.array([gx, gy, GOAL_HEIGHT])
            rgba = specs[roles.index("target")].rgba or (1.0, 1.0, 1.0, 1.0)
            marker = Marker("goal", gx, gy, GOAL_RADIUS, rgba, GOAL_HEIGHT, collides=True)
            centres = centres[1:]
        placed_specs = [
            replace(s, x=float(c[0]), y=float(c[1]), yaw=float(rng.uniform(-math.pi, math.pi)))
            for s, c in zip(specs, centres, strict=True)
        ]
        world = build_world(rng, placed_specs, roles, goal, marker, setup, split, assets)
        if world is not None:
            return world
    raise RuntimeError(f"no {task.name} layout settled in {MAX_WORLD_TRIES} tries")
