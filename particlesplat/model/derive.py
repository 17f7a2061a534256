"""Derived checkpoints: a trained model with keys changed that decide how its networks run, not what they
hold (no weight shape or learned value depends on them), so no retraining is needed. The shipped robot
model is one: its run's checkpoint with a cheaper refinement pass.
"""

from __future__ import annotations

from dataclasses import asdict
from os import PathLike

from particlesplat.core.choices import INFERENCE_KEYS
from particlesplat.core.errors import UserError
from particlesplat.model.config import (
    ModelConfig,
    flat_model_dict,
    model_config_from_dict,
    model_field,
    model_key,
    nested_model_dict,
    stored_model_config,
)
from particlesplat.model.io import model_from_checkpoint, read_checkpoint, save_checkpoint

# run state a derived checkpoint does not carry: it is a model, not a run to resume
RUN_STATE = ("optimizer", "optimizer_layout", "rng", "best", "run_avg")


class DeriveError(UserError):
    """A change a trained checkpoint cannot take."""


def derive_checkpoint(ckpt: dict, changes: dict[str, object], source: str, note: str = "") -> dict:
    """A copy of checkpoint dict ``ckpt`` (from ``source``) with the model keys in ``changes`` set
    (:data:`INFERENCE_KEYS` only, by nested path or flat name). Its config is written nested; its provenance says
    what changed ("derived"), after any earlier change; optimiser and RNG state are left out. Raises DeriveError
    or ConfigError naming the key."""
    old = stored_model_config(ckpt["config"], f"{source}: config")
    allowed = {model_field(k) for k in INFERENCE_KEYS}
    for key in changes:
        if model_field(key) not in allowed:
            known = ", ".join(INFERENCE_KEYS)
            raise DeriveError(f"{key}: not a key a trained model can change (those are: {known})")
    flat = flat_model_dict(changes, "model set")  # a key given flat and nested is refused naming both
    # as loading reads it: keys of removed branches dropped; written nested
    config = nested_model_dict({**asdict(old), **flat})
    new = model_config_from_dict(config, "model")  # validated
    state = dict(ckpt["state_dict"])
    if new.refine_steps > 0 and not any(k.startswith("refiner.") for k in state):
        raise DeriveError(f"refine.steps: {source} has no refiner weights (its refine.steps is {old.refine_steps})")
    if new.refine_steps == 0:
        state = {k: v for k, v in state.items() if not k.startswith("refiner.")}
    said = [
        f"{model_key(k)} {getattr(old, k)} -> {getattr(new, k)}" for k in flat if getattr(old, k) != getattr(new, k)
    ]
    if not said:
        raise DeriveError("nothing to change: every key already has that value")
    prov = dict(ckpt.get("provenance") or {})
    line = f"derived from {source} step {int(ckpt['step']):,}: " + ", ".join(said) + (f" ({note})" if note else "")
    prov["derived"] = f"{prov['derived']}; {line}" if prov.get("derived") else line
    out = {k: v for k, v in ckpt.items() if k not in RUN_STATE}
    return {**out, "config": config, "state_dict": state, "provenance": prov}


def write_derived(src: str | PathLike, dst: str | PathLike, changes: dict[str, object], note: str = "") -> ModelConfig:
    """Read ``src``, derive (:func:`derive_checkpoint`), check the copy loads, write ``dst`` atomically (never
    over ``src``). Returns the new model config."""
    from particlesplat.core.outputs import guard_outputs

    guard_outputs([("--out", dst)], [("CHECKPOINT", src)])
    ckpt = read_checkpoint(src)
    derived = derive_checkpoint(ckpt, changes, str(src), note)
    # what fails to load is the input with the changes: name both, not --out
    model = model_from_checkpoint(derived, f"{src} with {', '.join(changes)}")
    extra = {k: v for k, v in derived.items() if k not in ("config", "state_dict", "step", "config_sha256")}
    save_checkpoint(dst, model, derived["step"], extra)
    return model.config
