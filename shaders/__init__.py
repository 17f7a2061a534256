"""GLSL sources of the viewer's splat and id passes (installed as `viewer.shaders`)."""
