"""The one palette of the segmentation colours: particles, objects and their marks are coloured by key the same
way in the viewer's shader (its ``owner_color``, from :func:`shader_defines`), the viewer's panel swatches and
the headless figures (``particlesplat render --mode particles | objects | keypoints | boxes``).

Key k >= 0 (a particle index or an object number) gets hue ``k * HUE_STEP + HUE_OFFSET`` (golden-ratio steps:
neighbouring keys far apart on the colour wheel) at saturation ``SATURATION`` and value ``VALUE``; the background
(key < 0) is grey ``BACKGROUND``. Colours are RGB in [0, 1].
"""

from __future__ import annotations

import colorsys

import numpy as np

HUE_STEP = 0.6180339887  # the golden ratio's conjugate: turns of the colour wheel from one key to the next
HUE_OFFSET = 0.11  # the hue of key 0 (turns)
SATURATION = 0.75
VALUE = 0.95
BACKGROUND = 0.35  # the grey of the background (key < 0), every channel


def colour(key: int) -> tuple[float, float, float]:
    """The colour of key ``key`` (RGB in [0, 1]); grey :data:`BACKGROUND` for a key < 0."""
    if key < 0:
        return (BACKGROUND, BACKGROUND, BACKGROUND)
    return colorsys.hsv_to_rgb((key * HUE_STEP + HUE_OFFSET) % 1.0, SATURATION, VALUE)


def colour_map(labels: np.ndarray) -> np.ndarray:
    """(H, W) int keys (< 0: background) -> (H, W, 3) float64 colours."""
    out = np.empty(labels.shape + (3,))
    out[:] = BACKGROUND
    for key in np.unique(labels[labels >= 0]):
        out[labels == key] = colour(int(key))
    return out


def shader_defines() -> dict[str, str]:
    """The palette as GLSL ``#define`` values (``PALETTE_*``, floats) for the viewer's shaders."""
    values = {
        "HUE_STEP": HUE_STEP,
        "HUE_OFFSET": HUE_OFFSET,
        "SATURATION": SATURATION,
        "VALUE": VALUE,
        "BACKGROUND": BACKGROUND,
    }
    return {f"PALETTE_{k}": repr(float(v)) for k, v in values.items()}
