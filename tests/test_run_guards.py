"""Guards of the jobs themselves: the run-folder lock (owner, stale takeover), encode's trust in existing outputs,
the memory budget and its override, --device, float32 camera checks and implausible-scene warnings."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import torch
from model_data import TINY_MODEL, tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.core.errors import InputWarning, OptionError, UserError
from particlesplat.core.runlock import LOCK_NAME, RunLock, RunLockedError


def _dead_pid() -> int:
    return int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True).stdout)


def test_lock_names_a_live_owner_and_takes_over_a_dead_one(tmp_path, capsys):
    run = tmp_path / "run"
    held = RunLock(run).acquire()
    owner = json.loads((run / LOCK_NAME).read_text())
    assert owner["pid"] == os.getpid() and owner["host"] == socket.gethostname()
    with pytest.raises(RunLockedError, match=rf"{run}: in use by process {os.getpid()} on {socket.gethostname()}"):
        RunLock(run).acquire()
    held.release()
    assert not (run / LOCK_NAME).exists()
    # a process killed with -9 left its lock: taken over, with a message naming it
    (run / LOCK_NAME).write_text(json.dumps({"pid": _dead_pid(), "host": socket.gethostname(), "started": 1.0}))
    lock = RunLock(run).acquire()
    assert "taking over the stale lock of process" in capsys.readouterr().err
    assert json.loads((run / LOCK_NAME).read_text())["pid"] == os.getpid()
    lock.release()
    # another host's lock is never taken over (that host may still be training on a shared file system)
    (run / LOCK_NAME).write_text(json.dumps({"pid": _dead_pid(), "host": "elsewhere", "started": time.time()}))
    with pytest.raises(RunLockedError, match="in use by process .* on elsewhere, .* remove the lock file"):
        RunLock(run).acquire()


def test_two_trainings_of_one_folder_and_resume_of_a_finished_run(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=2, val_every=100)
    out = tmp_path / "run"
    train = ["train", "--config", str(cfg), "--data", str(data), "--out", str(out)]
    assert main(train) == 0
    assert not (out / LOCK_NAME).exists()  # given back at the end
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with RunLock(out):  # another process trains in it
        for extra in (["--resume"], ["--overwrite"]):
            with pytest.raises(RunLockedError, match=f"{out}: in use by process {os.getpid()}"):
                main(train + extra)
        assert {p.name: p.read_bytes() for p in out.iterdir() if p.name != LOCK_NAME} == before
    capsys.readouterr()
    assert main(train + ["--resume"]) == 0  # nothing left to train: said so, nothing changed
    assert "the run is complete (step 2 of 2); nothing to train" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_encode_trusts_only_files_that_prove_what_made_them(tmp_path_factory, tmp_path, capsys):
    from particlesplat.analysis.particle_arrays import ParticleArrays
    from particlesplat.model import ParticleSplat, save_checkpoint
    from particlesplat.model.config import model_config_from_dict

    data = tiny_dataset(tmp_path_factory) / "val"
    torch.manual_seed(0)
    ckpt = tmp_path / "a.pt"
    save_checkpoint(ckpt, ParticleSplat(model_config_from_dict(TINY_MODEL)), 0)
    out = tmp_path / "npz"
    enc = ["encode", "--data", str(data), "--out", str(out), "--checkpoint", str(ckpt), "--no-progress"]
    assert main(enc) == 0
    (npz,) = list(out.rglob("*.npz"))
    first = npz.read_bytes()
    assert main(enc) == 0 and npz.read_bytes() == first  # the same request: kept
    assert "wrote 0 .npz files" in capsys.readouterr().out
    # another --context: encoded again, and its meta says so
    assert main(enc + ["--context", "0,3"]) == 0
    assert ParticleArrays.load(npz).meta["context"] == [0, 3]
    assert "1 of them over a stale file" in capsys.readouterr().out
    # a truncated file and a killed run's temporary: re-encoded, and the temporary removed
    npz.write_bytes(npz.read_bytes()[:100])
    tmp = npz.parent / f".{npz.name}.{_dead_pid()}.0123abcd.tmp.npz"
    tmp.write_bytes(b"partial")
    assert main(enc) == 0
    assert ParticleArrays.load(npz).meta["context_request"] is None and not tmp.exists()
    # another checkpoint (other weights): its SHA-256 differs, so the file is redone
    torch.manual_seed(1)
    other = tmp_path / "b.pt"
    save_checkpoint(other, ParticleSplat(model_config_from_dict(TINY_MODEL)), 0)
    assert main([*enc[:-2], str(other), "--no-progress"]) == 0
    from particlesplat.analysis.particle_arrays import file_sha256

    assert ParticleArrays.load(npz).meta["checkpoint_sha256"] == file_sha256(other)
    # --force: every scene again
    capsys.readouterr()
    assert main([*enc[:-2], str(other), "--no-progress", "--force"]) == 0
    assert "wrote 1 .npz files" in capsys.readouterr().out


def test_memory_limit_from_the_environment(monkeypatch):
    from particlesplat.core.limits import MEMORY_ENV, BudgetError, check_memory, memory_limit, parse_bytes

    assert parse_bytes("16G") == 16 << 30 and parse_bytes("512m") == 512 << 20 and parse_bytes("1000") == 1000
    monkeypatch.setenv(MEMORY_ENV, "1G")
    assert memory_limit() == (1 << 30, f"{MEMORY_ENV}=1G")
    check_memory(0.9 * (1 << 30), "x")
    want = rf"scene: needs about 2.0 GiB, more than the memory limit of 1.0 GiB \({MEMORY_ENV}=1G"
    with pytest.raises(BudgetError, match=want):
        check_memory(2 << 30, "scene")
    monkeypatch.setenv(MEMORY_ENV, "lots")
    with pytest.raises(UserError, match=MEMORY_ENV):
        memory_limit()
    monkeypatch.delenv(MEMORY_ENV)
    limit, source = memory_limit()
    assert 0 < limit and ("machine" in source or "ulimit" in source)


def test_model_memory_is_counted_without_building_it():
    from particlesplat.model import ParticleSplat
    from particlesplat.model.config import model_config_from_dict
    from particlesplat.model.io import model_values

    cfg = model_config_from_dict(TINY_MODEL)
    real = ParticleSplat(cfg)
    assert model_values(cfg) == sum(t.numel() for t in real.parameters()) + sum(t.numel() for t in real.buffers())
    big = model_config_from_dict({**TINY_MODEL, "token_dim": 2048, "transformer_layers": 64})
    t0 = time.perf_counter()
    assert model_values(big) > 2e9 and time.perf_counter() - t0 < 10  # 8.6 GB of weights, never allocated


def test_device_is_checked_in_one_place():
    from particlesplat.core.device import resolve_device

    assert resolve_device("cpu") == torch.device("cpu") and resolve_device(" CPU ") == torch.device("cpu")
    for bad in ("cdua", "gpu", "cuda:x", "cpu:1"):
        with pytest.raises(OptionError, match="--device"):
            resolve_device(bad)
    if not torch.cuda.is_available():
        with pytest.raises(OptionError, match="no CUDA device"):
            resolve_device("cuda")


def test_camera_values_are_checked_in_float32():
    from particlesplat.core.camera import camera_problem

    K = np.array([[40.0, 0, 16], [0, 40, 16], [0, 0, 1]])
    c2w = np.eye(4)
    assert camera_problem(K, c2w, 32, 32) is None
    for k, v in (((0, 0), 0.0), ((0, 0), 1e-300), ((0, 2), 1e300), ((1, 1), -3.0)):
        bad = K.copy()
        bad[k] = v
        assert camera_problem(bad, c2w, 32, 32) is not None, (k, v)
    rot = c2w.copy()
    rot[0, 0] = 2.0  # not orthonormal
    assert "rigid" in camera_problem(K, rot, 32, 32)


def test_implausible_scene_warns_naming_the_file_and_field(tmp_path_factory, tmp_path):
    from particlesplat.data import read_scene

    scene = tmp_path / "s"
    shutil.copytree(next((tiny_dataset(tmp_path_factory) / "val").iterdir()), scene)
    meta = json.loads((scene / "transforms.json").read_text())
    for f in meta["frames"]:
        f["fl_x"], f["cx"] = 1e-3, -1e6
    meta["depth_unit_scale_factor"] = meta.get("depth_unit_scale_factor", 1e-3) * 1000  # millimetres read as metres
    for f in meta["frames"]:
        f.pop("depth_unit_scale_factor", None)
    (scene / "transforms.json").write_text(json.dumps(meta))
    with pytest.warns(InputWarning) as got:
        read_scene(scene)
    text = [str(w.message) for w in got]
    assert any("transforms.json: frames[0]: 'fl_x'/'fl_y' 0.001" in t for t in text), text
    assert any("'cx'/'cy' -1e+06" in t for t in text), text
    assert any("'depth_unit_scale_factor' makes the median depth" in t for t in text), text


def test_eval_fit_options_are_checked_before_the_work(tmp_path):
    for bad in (["--fit-steps", "-1"], ["--fit-lr", "0"], ["--fit-latents", "z_p,nope"]):
        with pytest.raises(OptionError, match="--fit-steps must be >= 0, --fit-lr > 0 and --fit-latents"):
            main(["eval", "--data", str(tmp_path / "absent"), *bad])


def test_pick_map_sums_object_weights_in_the_rasteriser_as_the_per_particle_map_does():
    """The editor's object map renders object labels as owners (one weight plane per object): the same labels as
    rendering one plane per particle and summing an object's planes, on a scene grown by duplicates."""
    from particlesplat.editing.editor import SceneEditor
    from particlesplat.editing.open_scene import demo_scenes, encode_scene
    from particlesplat.editing.operations import Duplicate
    from particlesplat.model import load_model
    from particlesplat.rendering.api import render

    torch.set_num_threads(1)
    model = load_model()
    enc = encode_scene(model, demo_scenes()[0])
    ed = SceneEditor(model, enc.particles, enc.all_cameras, enc.context)
    pick = ed.pick_for(next(i for i in range(ed.num_particles) if ed.is_active(i)))
    for i in range(3):
        ed.apply_op(Duplicate(pick=pick, offset=(0.1 * (i + 1), 0.0, 0.0)), f"op{i}")
    for frame in (enc.context[0], 0):
        cam = ed.frame_cameras[frame]
        with torch.no_grad():
            res = render(
                ed.decode(),
                cam.to("cpu", torch.float32),
                background=model.background_color().cpu(),
                owner_weights=True,
                num_owners=ed.num_particles,
            )
        want = res.segmentation(ed.objects()[: ed.num_particles])
        got = ed.object_map(frame)
        assert (got >= 0).any() and torch.equal(got, want), int((got != want).sum())
