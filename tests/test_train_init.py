"""``particlesplat train --init``: a run that starts from another checkpoint's weights (fine-tuning)."""

from __future__ import annotations

import pytest
import torch
import yaml
from model_data import tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.core.errors import UserError
from particlesplat.model import read_checkpoint
from particlesplat.training.trainer import Trainer


def _train(cfg, data, out, *extra) -> int:
    return main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), *extra])


def _with_model(cfg, **model):
    text = yaml.safe_load(cfg.read_text())
    text["model"].update(model)
    cfg.write_text(yaml.safe_dump(text))
    return cfg


def _trainer(cfg_path, data, out, init=None, resume=False) -> Trainer:
    from particlesplat.model import load_config

    cfg, tc = load_config(cfg_path)
    return Trainer(cfg, tc, data, out, "cpu", resume, init=init)


def test_init_copies_the_shared_weights_and_starts_the_rest_at_random(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    base = tiny_config(tmp_path / "base.yaml", steps=2, val_every=5)
    assert _train(base, data, tmp_path / "a") == 0
    source = read_checkpoint(tmp_path / "a" / "last.pt")
    # the same architecture with a per-view background of another latent width added
    wider = _with_model(tiny_config(tmp_path / "wider.yaml", steps=2, val_every=5), bg_per_view=True, d_bg=7)
    capsys.readouterr()
    tr = _trainer(wider, data, tmp_path / "b", init=tmp_path / "a" / "last.pt")
    report = capsys.readouterr().err
    state = tr.model.state_dict()
    fresh = _trainer(wider, data, tmp_path / "c").model.state_dict()  # the same seed from random initialisation
    theirs = source["state_dict"]
    copied = {n for n in state if n in theirs and theirs[n].shape == state[n].shape}
    assert copied and all(torch.equal(state[n], theirs[n]) for n in copied)
    assert any(n.startswith("bg_decoder.") for n in state) and not any(n.startswith("bg_decoder.") for n in theirs)
    for n in state.keys() - copied:  # the background decoder and the wider latent head: as a run from scratch
        assert torch.equal(state[n], fresh[n]), n
    assert "bg_encoder.head.weight" in state.keys() - copied  # 2 x d_bg output channels: another shape
    assert f"--init {tmp_path / 'a' / 'last.pt'} (step 2): {len(copied)} of this model's {len(state)}" in report
    assert "another shape in the checkpoint" in report and "bg_encoder.head" in report
    assert tr.step == 0
    assert tr.provenance_now()["init"] == f"{tmp_path / 'a' / 'last.pt'} (step 2)"


def test_an_init_run_trains_records_its_source_and_resumes(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    base = tiny_config(tmp_path / "base.yaml", steps=2, val_every=5)
    assert _train(base, data, tmp_path / "a") == 0
    tune = tiny_config(tmp_path / "tune.yaml", steps=3, val_every=5)
    src = tmp_path / "a" / "last.pt"
    assert _train(tune, data, tmp_path / "b", "--init", str(src), "--stop-after", "2") == 0
    ckpt = read_checkpoint(tmp_path / "b" / "last.pt")
    assert ckpt["step"] == 2 and ckpt["provenance"]["init"] == f"{src} (step 2)"
    # resumed, the run keeps its source; --init with --resume is refused before anything is read or written
    with pytest.raises(UserError, match="--init starts a run .* --resume continues one"):
        _train(tune, data, tmp_path / "b", "--resume", "--init", str(src))
    assert read_checkpoint(tmp_path / "b" / "last.pt")["step"] == 2
    assert _train(tune, data, tmp_path / "b", "--resume") == 0
    done = read_checkpoint(tmp_path / "b" / "last.pt")
    assert done["step"] == 3 and done["provenance"]["init"] == f"{src} (step 2)"
    from particlesplat.model.provenance import describe

    assert describe(done["provenance"]).startswith(f"provenance: from {src} (step 2); data")


def test_init_refuses_a_checkpoint_with_nothing_in_common(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=1, val_every=5)
    assert _train(cfg, data, tmp_path / "a") == 0
    ckpt = read_checkpoint(tmp_path / "a" / "last.pt")
    ckpt["state_dict"] = {"other." + n: v for n, v in ckpt["state_dict"].items()}
    ckpt.pop("config_sha256", None)
    torch.save(ckpt, tmp_path / "other.pt")
    with pytest.raises(UserError, match=r"other\.pt: --init: none of its \d+ weights has a name and shape"):
        _train(cfg, data, tmp_path / "b", "--init", str(tmp_path / "other.pt"))
    with pytest.raises(FileNotFoundError, match="--init .*missing.pt: no such file"):
        _train(cfg, data, tmp_path / "c", "--init", str(tmp_path / "missing.pt"))


def test_init_keeps_the_checkpoints_workspace_layer(tmp_path_factory, tmp_path):
    """A workspace layer copied from the checkpoint is not placed from the data again (which would reset its
    learned offsets and opacities)."""
    data = tiny_dataset(tmp_path_factory)
    layer = {"bg_static_grid": 0, "bg_static_points": 64}
    base = _with_model(tiny_config(tmp_path / "base.yaml", steps=2, val_every=5), **layer)
    assert _train(base, data, tmp_path / "a") == 0
    theirs = read_checkpoint(tmp_path / "a" / "last.pt")["state_dict"]
    assert float(theirs["static_bg.offset"].abs().max()) > 0  # trained: no longer where placement puts it
    tr = _trainer(base, data, tmp_path / "b", init=tmp_path / "a" / "last.pt")
    for n in ("anchor", "offset", "opacity_logit", "sh_dc"):
        assert torch.equal(tr.model.state_dict()[f"static_bg.{n}"], theirs[f"static_bg.{n}"]), n


def test_init_without_config_keeps_the_checkpoints_architecture_and_recipe(tmp_path_factory, tmp_path, capsys):
    """Without --config a fine-tune takes the checkpoint's own model config and its run's train section (the
    bundled recipe would build the tabletop architecture around the weights of another)."""
    data = tiny_dataset(tmp_path_factory)
    base = tiny_config(tmp_path / "base.yaml", steps=3, val_every=5, lr=1e-3)
    assert _train(base, data, tmp_path / "a", "--stop-after", "1") == 0
    src = tmp_path / "a" / "last.pt"
    capsys.readouterr()
    assert main(["train", "--init", str(src), "--data", str(data), "--out", str(tmp_path / "b")]) == 0
    err = capsys.readouterr().err
    assert f"--init without --config: the model config of {src}, the train section of {src} (3 steps; " in err
    a, b = read_checkpoint(src), read_checkpoint(tmp_path / "b" / "last.pt")
    assert b["config"] == a["config"] and b["train"] == a["train"] and b["step"] == 3
    assert f"{len(a['state_dict'])} of this model's {len(a['state_dict'])} weights copied" in err
    # a checkpoint that records no run (a shipped copy): the bundled recipe's train section
    from particlesplat.cli.train import init_config
    from particlesplat.core.bundled import recipe_path
    from particlesplat.model import load_config

    ckpt = read_checkpoint(src)
    del ckpt["train"]
    torch.save(ckpt, tmp_path / "shipped.pt")
    cfg, tc = init_config(tmp_path / "shipped.pt")
    assert tc == load_config(recipe_path())[1] and cfg.resolution == 32
    assert f"the train section of {recipe_path()}" in capsys.readouterr().err
