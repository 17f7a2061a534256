"""``particlesplat bench viewer``: the viewer's GL renderer against limacv/GaussianSplattingViewer (:mod:`.peer`),
and its per-pass profile (:mod:`.profile`)."""

from .run import main

__all__ = ["main"]
