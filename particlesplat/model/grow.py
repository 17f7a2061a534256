"""Function-preserving growth: start a wider model from a narrower one's weights.

A model config may widen the appearance latent (``d_obj``) and the particle decoder (``patch_channels``,
``patch_hidden``) over the checkpoint it starts from (``particlesplat train --init``). Every grown tensor keeps
the old weights in its leading block; what the new units feed into old units starts at zero, and the new units
themselves start as a fresh model draws them. So the grown model draws exactly what the old one drew, and the
new units receive gradients from the first step.
"""
from __future__ import annotations

import torch
from torch import Tensor

# the encoder's attribute head: rows [14 geometry | D z_f means | D z_f log-variances]
_GEOMETRY_ROWS = 14
_HEAD = "encoder.head."
# the only tensors that may change shape: the particle decoder and the z_f rows of the encoder's heads
_GROWABLE = ("fg_decoder.", _HEAD, "encoder.refine.")


def _embed(old: Tensor, fresh: Tensor) -> Tensor:
    """Old weights in the leading block of a fresh tensor; old output rows read nothing from new inputs.

    old: (o0, o1, *k) or (o0,); fresh: (n0 >= o0, n1 >= o1, *k) or (n0,) -> (n0, n1, *k) or (n0,)."""
    out = fresh.clone()
    if old.ndim == 1:
        out[:old.shape[0]] = old
        return out
    out[:old.shape[0]] = 0.0
    out[:old.shape[0], :old.shape[1]] = old
    return out


def _embed_head(old: Tensor, fresh: Tensor, d_old: int, d_new: int) -> Tensor:
    """The encoder head's rows (geometry, z_f means, z_f log-variances) each into their block.

    old: (14 + 2 d_old, ...); fresh: (14 + 2 d_new, ...) -> (14 + 2 d_new, ...)."""
    out = fresh.clone()
    g = _GEOMETRY_ROWS
    out[:g] = old[:g]
    out[g:g + d_old] = old[g:g + d_old]
    out[g + d_new:g + d_new + d_old] = old[g + d_old:]
    return out


def grow_state_dict(old: dict[str, Tensor], fresh: dict[str, Tensor], source: str = "checkpoint"
                    ) -> tuple[dict[str, Tensor], list[str]]:
    """Embed ``old`` (a narrower model's state dict) into ``fresh`` (the wider model's, freshly initialised).

    Tensors of equal shape are copied; the particle decoder's and the encoder's z_f rows may grow. Keys missing
    from ``old`` are left out (they start from their initialisation when loaded non-strictly); keys missing from
    ``fresh`` are kept, for the caller to report. Returns the state dict and the keys that grew.
    Raises ValueError naming ``source`` and the tensor for a shape that cannot be grown."""
    out, grown = {}, []
    d_old = d_new = None
    if _HEAD + "bias" in old and _HEAD + "bias" in fresh:
        d_old = (old[_HEAD + "bias"].shape[0] - _GEOMETRY_ROWS) // 2
        d_new = (fresh[_HEAD + "bias"].shape[0] - _GEOMETRY_ROWS) // 2
    for key, value in old.items():
        target = fresh.get(key)
        if target is None or target.shape == value.shape:
            out[key] = value
            continue
        fits = (key.startswith(_GROWABLE) and value.ndim == target.ndim
                and all(n >= o for n, o in zip(target.shape, value.shape)) and target.shape[2:] == value.shape[2:])
        if not fits:
            raise ValueError(f"{source}: {key} has shape {tuple(value.shape)}, this model config needs "
                             f"{tuple(target.shape)}: only d_obj, patch_channels and patch_hidden may differ, "
                             "and only grow")
        with torch.no_grad():
            if key.startswith(_HEAD):
                out[key] = _embed_head(value, target, d_old, d_new)
            else:
                out[key] = _embed(value, target)
        grown.append(key)
    return out, grown
