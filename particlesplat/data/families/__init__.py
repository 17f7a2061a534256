"""Scene families: generators that write the common scene format (docs/dataset.md).

``robot``: robot-workspace scenes composed and rendered by MuJoCo from robosuite's asset files (the
``sim`` extra). Importing this package loads nothing heavy.
"""

from __future__ import annotations

FAMILIES = ("tabletop", "robot")
# the generator a scene.json or synth.json names -> its family (tabletop scenes record only their generator)
GENERATOR_FAMILY = {
    "particlesplat.data.synth": "tabletop",
    "particlesplat.data.families.robot": "robot",
    "particlesplat.data.families.robot_wide": "robot",
}
CHECKPOINT_HELP = (
    "model checkpoint (default: the shipped model of the scenes' family: assets/model.pt, assets/robot/model.pt)"
)


def family_of(meta: object, where: str = "scene.json") -> str | None:
    """The family a scene's ``scene.json`` (or a dataset's ``synth.json``) records: its ``family``, else the one
    its ``generator`` implies; None when it records neither. A ``family`` that is not one of :data:`FAMILIES` is an
    error naming ``where`` (it would otherwise open with the tabletop model in silence)."""
    if not isinstance(meta, dict):
        return None
    if "family" in meta:
        family = meta["family"]
        if not isinstance(family, str) or family not in FAMILIES:
            from particlesplat.core.errors import UserError, short_repr

            raise UserError(f"{where}: key 'family' is {short_repr(family)}, not one of {', '.join(FAMILIES)}")
        return family
    generator = meta.get("generator")
    return GENERATOR_FAMILY.get(generator) if isinstance(generator, str) else None
