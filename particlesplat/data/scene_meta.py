"""What a scene generator records about a scene folder beyond its frames (``scene.json``, docs/dataset.md):
here, where its cameras look (``look_at``, ``distance``), so that the default view, the orbit and ``--look``
follow the scene's own scale rather than one family's."""

from __future__ import annotations

import json
import math
from os import PathLike
from pathlib import Path

from particlesplat.core.errors import one_line, short_repr
from particlesplat.core.viewpoints import Framing
from particlesplat.data.scene import SceneFormatError

SCENE_META = "scene.json"
MAX_SCENE_META_BYTES = 16 << 20


def read_framing(folder: str | PathLike) -> Framing | None:
    """The framing ``folder/scene.json`` records: ``look_at`` (3 numbers, world metres) and, when present,
    ``distance`` (metres, > 0). None when the folder has no scene.json or it records no ``look_at`` (the
    cameras alone then frame the scene). SceneFormatError names the file and the key of a bad value."""
    path = Path(folder) / SCENE_META
    if not path.is_file():
        return None
    size = path.stat().st_size
    if size > MAX_SCENE_META_BYTES:
        raise SceneFormatError(f"{path}: {size} bytes, more than the {MAX_SCENE_META_BYTES} a {SCENE_META} may have")
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise SceneFormatError(f"{path}: not valid JSON ({one_line(e, 200)})") from None
    if not isinstance(meta, dict) or meta.get("look_at") is None:
        return None
    look_at = meta["look_at"]
    if not (isinstance(look_at, list) and len(look_at) == 3 and all(_finite(v) for v in look_at)):
        raise SceneFormatError(f"{path}: key 'look_at' must be 3 finite numbers (metres), got {short_repr(look_at)}")
    distance = meta.get("distance")
    if distance is not None and not (_finite(distance) and distance > 0):
        raise SceneFormatError(f"{path}: key 'distance' must be a positive number (metres), got {short_repr(distance)}")
    return Framing(
        (float(look_at[0]), float(look_at[1]), float(look_at[2])), None if distance is None else float(distance)
    )


def _finite(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) < 1e6
