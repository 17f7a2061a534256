"""The names commands offer as choices, light to import (no torch): a command's ``--help`` and its argument errors
come before torch loads. Render modes, object centres, the latents a fit may move, a checkpoint's inference keys."""

from __future__ import annotations

from typing import Literal

RenderMode = Literal["rgb", "depth", "particles", "objects", "foreground", "background", "keypoints", "boxes"]
MODES: tuple[str, ...] = ("rgb", "depth", "particles", "objects", "foreground", "background", "keypoints", "boxes")
NEEDS_PARTICLES: tuple[str, ...] = ("particles", "objects", "foreground", "background", "keypoints", "boxes")

ObjectCentre = Literal["resting", "weighted"]
OBJECT_CENTRES: tuple[ObjectCentre, ...] = ("resting", "weighted")

# the latents a fit may move; z_t (which particles exist) and the background stay as encoded
FITTED = ("z_p", "z_s", "z_d", "z_e", "z_f")
# what a fit moves unless told otherwise: the appearance alone, so the particles (and the objects they form) stay
DEFAULT_FIT = ("z_f",)

# model keys a trained checkpoint may change (by their nested path; the flat name, refine_steps, is read too), and
# what each decides
INFERENCE_KEYS: dict[str, str] = {
    "refine.steps": "amortised refinement steps (0 leaves the refiner out and drops its weights)",
    "refine.scale": "fraction of the resolution the refinement renders the context views at",
    "refine.keep": "Gaussians per particle the refinement renders (0: all)",
    "refine.static": "how the refinement draws the static layer: render (among the particles) or behind (the "
    "encoder's full-size render of it, pooled, behind them)",
    "particles_per_view": "foreground particles kept per context view",
    "keypoints.min_separation": "least distance between kept keypoints (normalised image units)",
    "background.mask_threshold": "z_t above which a particle is active and draws",
    "background.colour_from_views": "the colour behind the Gaussians is read from each scene's context views (the "
    "median colour below the support surface: floor, table sides) instead of the learned one",
    "background.hidden_from_views": "a per-view background block an object hides is drawn in the colour of the "
    "support surface its view shows (with fg_evidence) instead of the colour its latent guesses",
    "background.support_map": "where no Gaussian draws the support surface, a render shows a top-down map of it "
    "read from each scene's context views (with colour_from_views' colour around it) instead of one colour",
    "background.opaque_under_objects": "a per-view background block under an object (within 4 pixels of its "
    "evidence) that no particle's box covers any longer draws the support surface, opaque, in the support map's "
    "colour (with hidden_from_views): the table where an edit moved or removed the object; the map then leaves out "
    "the objects' feet, and an unedited scene renders as before but for that",
    "support.cut": "metres below the support surface under which a particle Gaussian does not draw (< 0: off)",
}

# ``eval --protocol``: which views an evaluation encodes and which it scores.
# sampled (the default): the validation sampler's views (two context views 5-20 frames apart on the trajectory,
#   four targets between them; one context view: the front frame and two targets);
# paper: the paper's RLBench protocol, context frames 6 and 14, targets 6, 8, 10, 12 and 14;
# inputs: the context views rendered at their own cameras (how well a model redraws what it was given).
EvalProtocol = Literal["sampled", "paper", "inputs"]
EVAL_PROTOCOLS: tuple[EvalProtocol, ...] = ("sampled", "paper", "inputs")
PAPER_CONTEXT_FRAMES = (6, 14)
PAPER_TARGET_FRAMES = (6, 8, 10, 12, 14)


def check_protocol(protocol: str, context: int) -> None:
    """Refuse (:class:`OptionError`) an unknown ``protocol`` or the paper's protocol with other than two context
    views."""
    from particlesplat.core.errors import OptionError

    if protocol not in EVAL_PROTOCOLS:
        raise OptionError(f"--protocol must be one of {', '.join(EVAL_PROTOCOLS)}, got {protocol!r}")
    if protocol == "paper" and context != 2:
        raise OptionError(
            f"--protocol paper encodes two context views (frames {PAPER_CONTEXT_FRAMES[0]} and "
            f"{PAPER_CONTEXT_FRAMES[1]}); drop --context 1 or choose another protocol"
        )
