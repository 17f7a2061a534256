"""``particlesplat bench viewer``: the viewer's GL renderer against limacv/GaussianSplattingViewer (:mod:`.peer`)
(:mod:`.run`), and with ``--profile`` its per-pass profile (:mod:`.profile`)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """The benchmark's entry point: ``--profile`` runs the per-pass profile, anything else the comparison."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--profile" in argv:
        from .profile import main as profile_main

        argv.remove("--profile")
        return profile_main(argv)
    from .run import main as run_main

    return run_main(argv)


__all__ = ["main"]
