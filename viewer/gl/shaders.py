"""The GLSL sources of ``shaders/``, with the library's constants injected as ``#define`` lines (a colour or a
rendering constant is defined once, in the library, never written in GLSL)."""

from __future__ import annotations

from particlesplat.core import palette
from particlesplat.core.bundled import data_dir

from .caps import shader_constants


def load_shader(name: str, defines: dict[str, str | int] | None = None) -> str:
    """Source of ``shaders/<name>`` with ``#define`` lines inserted after ``#version``: the library's
    compositing constants (:func:`~viewer.gl.caps.shader_constants`) and palette
    (:func:`particlesplat.core.palette.shader_defines`), then ``defines``."""
    src = (data_dir("viewer.shaders", "shaders") / name).read_text()
    first, rest = src.split("\n", 1)
    constants = {**shader_constants(), **palette.shader_defines(), **(defines or {})}
    lines = [f"#define {k} {v}" for k, v in constants.items()]
    return "\n".join([first, *lines, rest])
