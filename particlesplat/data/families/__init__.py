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


def family_of(meta: object) -> str | None:
    """The family a scene's ``scene.json`` (or a dataset's ``synth.json``) records: its ``family``, else the one
    its ``generator`` implies; None when it records neither."""
    if not isinstance(meta, dict):
        return None
    family = meta.get("family")
    if isinstance(family, str) and family in FAMILIES:
        return family
    generator = meta.get("generator")
    return GENERATOR_FAMILY.get(generator) if isinstance(generator, str) else None
