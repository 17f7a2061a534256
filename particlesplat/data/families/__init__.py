"""Scene families: generators that write the common scene format (docs/dataset.md), registered here once each.

A family's :class:`Family` holds every fact the rest of the program needs of it: the name ``--family`` and
``scene.json`` give, the generator ``particlesplat synth`` runs, the generator names its scenes record, its shipped
model and demo scenes, the static layer of its model, the camera distances and robot convention ``scene check``
judges a capture against. Commands read these through :func:`families` and :func:`get_family` and never name a
family themselves; registering one more family (:func:`register`) adds it to ``--family``'s choices, to what
``scene.json`` may record and to every message that lists the families.

Importing this package loads nothing heavy: a generator is named as ``"module:function"`` and imported only when a
dataset is written (``robot``'s needs MuJoCo, the ``sim`` extra).
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Literal

# a floor grid (model.background.static_grid), free Gaussians (model.background.static_points)
StaticLayer = Literal["grid", "points"]
# a generator entry: (out folder, scenes per split, seed, the synth command's options) -> seconds per new scene
Generator = Callable[[Path, dict[str, int], int, argparse.Namespace], list[float]]


@dataclass(frozen=True)
class Family:
    """One scene family, as registered.

    Attributes:
        name: what ``--family`` and ``scene.json``'s ``family`` say (e.g. ``"robot"``).
        summary: one phrase for ``synth --help``: what its scenes are.
        title: how ``model info`` names the family of a model whose static layer is ``static_layer``.
        generator: ``"module:function"`` of its :data:`Generator`, imported when ``synth`` runs.
        generators: the ``generator`` values its scenes' ``scene.json`` and its datasets' ``synth.json`` record;
            each implies this family where no ``family`` key is recorded.
        shipped_model: its shipped model, a path under ``assets/``: what its scenes open with without
            ``--checkpoint``.
        demo_scenes: the folder of its demo scenes under ``assets/`` (need not exist).
        static_layer: the static layer its models learn or learned: ``"grid"`` or ``"points"`` (``model info``
            names a checkpoint's family by it; a model that reads a robot's state is the robot family's).
        camera_distances: (min, max) metres from the training cameras to the point they look at; ``scene check``
            judges a capture's scale against them.
        robot: its scenes hold a robot, its base at -x of the table (robosuite's convention): ``scene check``
            measures the turn about z from ``scene.json``'s ``robot_base`` or the depth.
        heldout_worlds: the ``synth --world`` values that have a held-out split (``--heldout``).
        model_world: the ``synth --world`` its shipped model was trained on: what ``synth`` writes for this family
            when ``--world`` is not given (None: the family has one world).
        table_height: metres from the floor up to the table top of its scenes whose ``scene.json`` records a table
            (``table_half_extent``); edits put an object slid past the table's edge on the floor this far below
            (:func:`particlesplat.data.scene_meta.read_support`). None: its scenes have no table.
    """

    name: str
    summary: str
    title: str
    generator: str
    generators: tuple[str, ...]
    shipped_model: str
    demo_scenes: str
    static_layer: StaticLayer
    camera_distances: tuple[float, float]
    robot: bool = False
    heldout_worlds: tuple[str, ...] = ()
    model_world: str | None = None
    table_height: float | None = None

    def generate(self, out: Path, counts: dict[str, int], seed: int, options: argparse.Namespace) -> list[float]:
        """Write ``counts[split]`` scenes per split under ``out`` with this family's generator (imported now);
        ``options``: the ``synth`` command's (``res``, ``workers``, ``cameras``, ``world``, ``arm``). Returns the
        seconds each new scene took."""
        module, _, function = self.generator.partition(":")
        entry: Generator = getattr(importlib.import_module(module), function)
        return entry(out, counts, seed, options)

    def shipped_model_path(self) -> Path:
        """Its shipped model in the installed ``particlesplat.assets`` package (or the checkout's ``assets/``)."""
        from particlesplat.core.bundled import bundled_assets

        return bundled_assets() / self.shipped_model


_REGISTRY: dict[str, Family] = {}
DEFAULT_FAMILY = "tabletop"  # what synth writes, and what a scene that records no family is taken for


def register(family: Family) -> Family:
    """Add ``family`` to the registry (after the ones registered before it). ValueError when its name, or a
    generator name it records, is already another family's."""
    if family.name in _REGISTRY:
        raise ValueError(f"scene family {family.name!r} is registered already")
    for other in _REGISTRY.values():
        shared = set(family.generators) & set(other.generators)
        if shared:
            raise ValueError(f"scene family {family.name!r}: generator {sorted(shared)[0]!r} is {other.name!r}'s")
    _REGISTRY[family.name] = family
    return family


def families() -> tuple[Family, ...]:
    """The registered families, in the order they were registered (the default one first)."""
    return tuple(_REGISTRY.values())


def family_names() -> tuple[str, ...]:
    """The registered families' names (``--family``'s choices)."""
    return tuple(_REGISTRY)


def names_text() -> str:
    """The registered names for a message: ``"tabletop, robot"``."""
    return ", ".join(_REGISTRY)


def get_family(name: str) -> Family:
    """The registered family ``name``; ValueError naming the registered ones when there is none."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"no scene family {name!r} (registered: {names_text()})") from None


def family_of_generator(generator: str) -> str | None:
    """The family whose scenes record ``generator`` (:attr:`Family.generators`), or None."""
    return next((f.name for f in _REGISTRY.values() if generator in f.generators), None)


def shipped_models_text() -> str:
    """Every family's shipped model for a help line: ``"assets/model.pt, assets/robot/model.pt"``."""
    return ", ".join(f"assets/{f.shipped_model}" for f in _REGISTRY.values())


def shipped_model_named(path: str | PathLike) -> Path | None:
    """The shipped model that ``path`` names the way ``model info``, the viewer and edit files name one
    (``assets/robot/model.pt``, :attr:`Family.shipped_model` under ``assets/``), when no file exists at ``path`` as
    given (a file of that name in the working directory wins); else None. So a shipped model's name opens it from
    any working directory, installed or in a checkout."""
    given = Path(path)
    if given.is_absolute() or given.exists():
        return None
    for family in _REGISTRY.values():
        if given.as_posix() == f"assets/{family.shipped_model}":
            return family.shipped_model_path()
    return None


def checkpoint_help() -> str:
    """``--checkpoint``'s help where the scenes' family picks the model."""
    return f"model checkpoint (default: the shipped model of the scenes' family: {shipped_models_text()})"


def family_of(meta: object, where: str = "scene.json") -> str | None:
    """The family a scene's ``scene.json`` (or a dataset's ``synth.json``) records: its ``family``, else the one
    its ``generator`` implies; None when it records neither. A ``family`` that is not a registered one is an
    error naming ``where`` and the registered families (it would otherwise open with the default model in
    silence)."""
    if not isinstance(meta, dict):
        return None
    if "family" in meta:
        family = meta["family"]
        if not isinstance(family, str) or family not in _REGISTRY:
            from particlesplat.core.errors import UserError, short_repr

            raise UserError(f"{where}: key 'family' is {short_repr(family)}, not one of {names_text()}")
        return family
    generator = meta.get("generator")
    return family_of_generator(generator) if isinstance(generator, str) else None


register(
    Family(
        name="tabletop",
        summary="spheres, boxes and cylinders on a checkered floor, ray-cast",
        title="tabletop",
        generator="particlesplat.data.synth:generate_family",
        generators=("particlesplat.data.synth",),
        shipped_model="model.pt",
        demo_scenes="scenes",
        static_layer="grid",
        camera_distances=(3.0, 3.6),  # the generator's draws (tabletop.DISTANCE_RANGE)
    )
)
register(
    Family(
        name="robot",
        summary="a Panda arm at a table with household objects, MuJoCo + robosuite's assets; test scenes carry "
        "ground-truth edits",
        title="robot workspace",
        generator="particlesplat.data.families.robot_synth:generate_family",
        generators=("particlesplat.data.families.robot", "particlesplat.data.families.robot_wide"),
        shipped_model="robot/model.pt",
        demo_scenes="robot/scenes",
        static_layer="points",  # the narrow robot model's; the shipped one reads the robot's state instead
        # the rigs' distances: the wide world's arc and RLBench-style cameras (0.8-1.2 m), the narrow world's arc
        # (0.85-1.0 m) and its fixed cameras (about 1.0-1.25 m)
        camera_distances=(0.8, 1.25),
        robot=True,
        heldout_worlds=("wide",),
        table_height=0.8,  # robosuite's table arena: a 0.8 m box on the floor (robot_compose reads its top there)
        model_world="wide",  # assets/robot/model.pt: the robot-wide run (docs/robot-workspaces.md)
    )
)
