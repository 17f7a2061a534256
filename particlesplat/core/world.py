"""The world frame every scene and model shares (docs/dataset.md): metres, +z up, and the surface objects rest
on, the tabletop family's floor and the robot family's table top, at z = :data:`SUPPORT_Z`.
``particlesplat scene check`` brings a capture into it."""

SUPPORT_Z = 0.0  # metres: the height of the support surface objects rest on
ON_SUPPORT = 0.01  # metres about the support surface within which a point seen in depth lies on it
BELOW_SUPPORT = 0.02  # metres under it below which a point seen in depth lies past it (the floor, a table's sides)
