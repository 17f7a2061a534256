"""Core types and helpers: cameras, Gaussians, spherical harmonics, viewing cameras, errors, atomic writes,
safe YAML, lazy exports."""
