"""One episode, decision by decision: observe (both views' RGB-D, the robot's state, the objects' states), ask a
decider for the next keypose, let the controller take the arm there; at the end, the task's success from the
simulator's state.

The decider is any function of (the world, the observation) returning a :class:`Keypose` or None (done): the
scripted expert (:func:`expert_decider`) reads the world's privileged state; a learned policy reads only the
observation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .control import ArmController, Keypose, matrix_to_quat
from .expert import Expert
from .tasks import Task
from .world import RigRenderer, TaskWorld

MAX_DECISIONS = 16  # an episode ends after this many keyposes at most (a clean expert episode takes 6)


@dataclass
class Observation:
    """What is recorded at one decision (K objects, V = 2 views of H x W pixels).

    Attributes:
        rgb: (V, H, W, 3) uint8; depth: (V, H, W) float32 planar metres (0: nothing); masks: (V, H, W) uint8
            (object k + 1, 0 elsewhere). None where the views were not rendered (an episode's final state).
        joints: (7,) arm joint angles, radians; fingers: (2,) finger joints, metres; gripper: the gripper's
            command (1 open, 0 closed).
        eef: (7,) the grasp point (3, metres) and the hand's quaternion (4, w x y z), world.
        object_positions: (K, 3) body origins, metres; object_quaternions: (K, 4) w x y z; object_boxes: (K, 2, 3)
            their axis-aligned boxes' min and max corners, metres.
        sim_time: the simulator's clock, seconds.
    """

    joints: np.ndarray
    fingers: np.ndarray
    gripper: float
    eef: np.ndarray
    object_positions: np.ndarray
    object_quaternions: np.ndarray
    object_boxes: np.ndarray
    sim_time: float
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None
    masks: np.ndarray | None = None


@dataclass
class EpisodeResult:
    """An episode: ``steps`` (observation, keypose taken) per decision, the ``final`` state (no views),
    ``success``, whether every keypose was ``reached``, seconds of wall and simulated time, and per decision the
    wall seconds from the observation to the keypose (rendering the views when asked, the decider's work): what a
    policy costs a decision, without the controller's motion."""

    steps: list[tuple[Observation, Keypose]] = field(default_factory=list)
    final: Observation | None = None
    success: bool = False
    reached: bool = True
    wall_seconds: float = 0.0
    sim_seconds: float = 0.0
    decision_seconds: list[float] = field(default_factory=list)


Decider = Callable[[TaskWorld, Observation], Keypose | None]


def observe(world: TaskWorld, controller: ArmController, renderer: RigRenderer | None) -> Observation:
    """The world's state now (and the rig's views with a ``renderer``)."""
    joints, fingers = world.arm_state()
    pos, rot = controller.eef_pose()
    positions, quats = world.poses()
    obs = Observation(
        joints,
        fingers,
        float(controller.opening),
        np.concatenate([pos, matrix_to_quat(rot)]),
        positions,
        quats,
        np.array([np.stack(world.box(k)) for k in range(len(world.specs))]).reshape(-1, 2, 3),
        float(world.comp.data.time),
    )
    if renderer is not None:
        views = renderer.render()
        obs.rgb, obs.depth, obs.masks = views.rgb, views.depth, views.masks
    return obs


def expert_decider(task: Task) -> Decider:
    """The scripted expert of one episode (:class:`Expert`), reading the world's privileged state."""
    expert = Expert(task)

    def decide(world: TaskWorld, obs: Observation) -> Keypose | None:
        return expert.next_keypose(world, obs.eef[:3], obs.fingers)

    return decide


def run_episode(
    world: TaskWorld,
    task: Task,
    decide: Decider,
    render: bool = True,
    max_decisions: int = MAX_DECISIONS,
    stop_on_success: bool = False,
) -> EpisodeResult:
    """Run one episode in ``world`` (built by :func:`.tasks.build_task_world`) with ``decide`` choosing the
    keyposes; the views are rendered at each decision when ``render``. It ends when ``decide`` returns None,
    after ``max_decisions``, or (``stop_on_success``, as RLBench ends an episode) once the task has succeeded."""
    import_start = time.perf_counter()
    from particlesplat.data.families.robot_assets import import_mujoco

    controller = ArmController(import_mujoco(), world.comp)
    renderer = RigRenderer(world) if render else None
    result = EpisodeResult()
    start_sim = float(world.comp.data.time)
    try:
        for _ in range(max_decisions):
            decision_start = time.perf_counter()
            obs = observe(world, controller, renderer)
            keypose = decide(world, obs)
            result.decision_seconds.append(time.perf_counter() - decision_start)
            if keypose is None:
                break
            result.steps.append((obs, keypose))
            result.reached &= controller.execute(keypose).reached
            if stop_on_success and task.success(world):
                break
        result.final = observe(world, controller, None)
        result.success = bool(task.success(world))
    finally:
        if renderer is not None:
            renderer.close()
    result.wall_seconds = time.perf_counter() - import_start
    result.sim_seconds = float(world.comp.data.time) - start_sim
    return result
