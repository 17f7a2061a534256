"""Hostile input on the newer surfaces: outputs over inputs (the commands, the benchmarks' --json, the viewer's
screenshots, exports, edit files and autosaves), run folders, checkpoints' other fields, logs, threads, synth's
folder, render passes past the memory limit in eval, encode and training. Each command runs in its own process under
the memory cap (``runner.py``; the viewer's panel without a window, ``viewer_panel.py``); a refusal is one line,
exit 2, nothing changed; a case that must succeed does so within the cap."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]

from hostile_files import (  # noqa: E402
    big_config_checkpoint,
    big_gaussians_ply,
    big_log,
    checkpoint_with,
    edit_json,
    lock_run,
    lying_npz,
)
from model_data import TINY_MODEL, tiny_config, tiny_dataset  # noqa: E402
from test_hostile_suite import CAP_MB, _lines  # noqa: E402

PS, VIEWER = "particlesplat", "particlesplat-viewer"
WIDE_MODEL = {**TINY_MODEL, "patch_gaussians": 16, "s_min": 20.0, "s_max": 40.0}  # every Gaussian covers its views
WIDE_LIMIT = {"PARTICLESPLAT_MEMORY_LIMIT": "24M"}  # above the encoder's estimate (10 MB), below the render passes
ROOT = HERE.parent.parent
TAB0, ROB0 = ROOT / "assets" / "scenes" / "scene_00000", ROOT / "assets" / "robot" / "scenes" / "scene_00019"


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    from particlesplat.cli.main import main
    from particlesplat.model import ParticleSplat, save_checkpoint
    from particlesplat.model.config import model_config_from_dict

    data = tiny_dataset(tmp_path_factory)
    w = tmp_path_factory.mktemp("surfaces")
    torch.manual_seed(0)
    good = w / "good.pt"
    save_checkpoint(good, ParticleSplat(model_config_from_dict(TINY_MODEL)), 0)
    scene = w / "split" / "scene"
    shutil.copytree(next((data / "val").iterdir()), scene)
    cfg = tiny_config(w / "tiny.yaml", steps=4, val_every=2, ckpt_every=1)
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(w / "run"), "--stop-after", "2"]) == 0
    for name in ("locked_run", "init_run", "no_config_run"):
        shutil.copytree(w / "run", w / name)
    lock_run(w / "locked_run", os.getpid())
    (w / "no_config_run" / "config.yaml").unlink()
    # a run that stopped before its first checkpoint, as earlier versions left it: its config.yaml (and log)
    (w / "unstarted").mkdir()
    shutil.copy(w / "run" / "config.yaml", w / "unstarted" / "config.yaml")
    shutil.copy(w / "run" / "metrics.jsonl", w / "unstarted" / "metrics.jsonl")
    other = yaml.safe_load(cfg.read_text())
    other["train"]["batch_size"] = 1
    (w / "other_batch.yaml").write_text(yaml.safe_dump(other))
    threads = yaml.safe_load(cfg.read_text())
    threads["train"].update(num_threads=1024, steps=1, val_every=100)
    (w / "threads.yaml").write_text(yaml.safe_dump(threads))
    # logs: one bad record each, before the last line
    val = json.dumps({"step": 2, "val": {"psnr": 20.0, "fg_ari": 0.5}})
    logs = {
        "psnr_text": json.dumps({"step": 1, "val": {"psnr": "high", "fg_ari": 0.5}}),
        "step_nan": '{"step": NaN, "val": {"psnr": 20.0}}',
        "no_step": json.dumps({"val": {"psnr": 20.0}}),
        "utf8": b"\xff\xfe{}".decode("latin-1"),
        "nested": "[" * 100_000 + "]" * 100_000,
    }
    for name, line in logs.items():
        (w / "logs" / name).mkdir(parents=True)
        (w / "logs" / name / "metrics.jsonl").write_bytes(line.encode("latin-1") + b"\n" + val.encode() + b"\n")
    (w / "logs" / "odd").mkdir()
    odd = [
        {"step": 1, "val": {"psnr": None, "fg_ari": 0.5}},
        {"step": 2, "val": {"psnr": float("inf")}},
        json.loads(val),
    ]
    (w / "logs" / "odd" / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in odd))
    (w / "logs" / "big").mkdir()
    big_log(w / "logs" / "big" / "metrics.jsonl", 150)
    # checkpoints whose other fields or values are wrong
    checkpoint_with(good, w / "prov.pt", provenance={"wall_hours": "many", "data": "x"})
    checkpoint_with(good, w / "train.pt", train={"batch_size": "four"})
    checkpoint_with(good, w / "huge.pt", weights=lambda v: v * 1e30)
    checkpoint_with(good, w / "int.pt", weights=lambda v: (v * 100).to(torch.int64))
    big_config_checkpoint(good, w / "big_init.pt", token_dim=2048, transformer_layers=64)
    # with its run's train section, as a trainer writes it (without one, --init reads the shipped recipe's)
    checkpoint_with(w / "big_init.pt", w / "big_init.pt", train=yaml.safe_load(cfg.read_text())["train"])
    big_config_checkpoint(good, w / "mismatch.pt", channels=16)  # its weights are of channels 8
    # render passes past the limit: Gaussian scales of 20-40 cells (s_min, s_max), 512 a particle, in 32^2 views
    save_checkpoint(w / "wide.pt", ParticleSplat(model_config_from_dict(WIDE_MODEL)), 0)
    wide = yaml.safe_load(cfg.read_text())
    wide["model"] = WIDE_MODEL
    (w / "wide.yaml").write_text(yaml.safe_dump(wide))
    shutil.copytree(w / "run", w / "wide_run")  # --overwrite refused before the run starts: the old run is kept
    shutil.copytree(w / "run", w / "nan_bench_run")
    checkpoint_with(w / "run" / "last.pt", w / "nan_bench_run" / "last.pt", weights=lambda v: v * float("nan"))
    # synth: a folder another synth holds; a robot scene (scene.json) in a folder without synth.json
    (w / "synth_locked").mkdir()
    lock_run(w / "synth_locked", os.getpid())
    robot_scene = w / "synth_mixed" / "train" / "scene_00000"
    robot_scene.mkdir(parents=True)
    (robot_scene / "scene.json").write_text(json.dumps({"generator": "particlesplat.data.families.robot"}))
    rgb = scene / json.loads((scene / "transforms.json").read_text())["frames"][4]["file_path"]
    _scene_world(w, scene)
    return {"w": w, "data": data, "scene": scene, "cfg": cfg, "good": good, "rgb": rgb}


def _scene_copy(scene: Path, folder: Path, transforms=None, meta=None) -> Path:
    """A copy of ``scene`` at ``folder`` with its transforms.json and scene.json edited in place."""
    shutil.copytree(scene, folder)
    if transforms:
        edit_json(folder / "transforms.json", transforms)
    if meta:
        edit_json(folder / "scene.json", meta)
    return folder


def _scene_world(w: Path, scene: Path) -> None:
    """Scenes, folders and files of the family, number, reader and record classes."""
    _scene_copy(scene, w / "family" / "drone" / "s", meta=lambda m: m.update(family="drone"))
    _scene_copy(scene, w / "family" / "number" / "s", meta=lambda m: m.update(family=123))
    _scene_copy(scene, w / "family" / "mixed" / "a")
    _scene_copy(ROB0, w / "family" / "mixed" / "b")
    joints = json.loads((ROB0 / "scene.json").read_text())["arm_joints_rad"]
    _scene_copy(ROB0, w / "robot" / "rad100", meta=lambda m: m.update(arm_joints_rad=[100.0] * 7))
    # joint 4 (index 3) within its limits (-3.07, -0.07) but above what training drew (up to about -0.49)
    outside = [*joints[:3], -0.2, *joints[4:]]
    _scene_copy(ROB0, w / "robot" / "plus06", meta=lambda m: m.update(arm_joints_rad=outside))

    def every(key, value):
        return lambda m: [f.update({key: value(f)}) for f in m["frames"]]

    def ecef(m):
        for f in m["frames"]:
            f["transform_matrix"][0][3] += 4.2e6

    _scene_copy(scene, w / "numbers" / "depth", transforms=lambda m: m.update(depth_unit_scale_factor=1e17))
    _scene_copy(scene, w / "numbers" / "ecef", transforms=ecef)
    _scene_copy(scene, w / "numbers" / "distance", meta=lambda m: m.update(look_at=[0, 0, 0.2], distance=1e-300))
    _scene_copy(scene, w / "numbers" / "far_framing", meta=lambda m: m.update(look_at=[50.0, 50.0, 0.0], distance=1.0))
    _scene_copy(scene, w / "centre" / "nan_centre", meta=lambda m: m["objects"][0].update(center=[float("nan")] * 3))
    _scene_copy(
        scene,
        w / "rig" / "point",
        transforms=every(
            "transform_matrix",
            lambda f: [[*row[:3], [-2.4, 1.4, 1.65, 1][i]] for i, row in enumerate(f["transform_matrix"])],
        ),
    )

    def no_depth(m):
        m["depth_unit_scale_factor"] = "abc"
        for f in m["frames"]:
            f.pop("depth_file_path")

    _scene_copy(scene, w / "rig" / "scale", transforms=no_depth)
    big = _scene_copy(scene, w / "readers" / "big" / "s")
    (big / "scene.json").write_text(json.dumps({"pad": "x" * (17 << 20)}))
    nested = _scene_copy(scene, w / "readers" / "nested" / "s")
    (nested / "scene.json").write_text("[" * 100_000 + "]" * 100_000)
    text = _scene_copy(scene, w / "readers" / "text" / "s")
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_text("comment", "a" * (4 << 20), zip=True)  # 4 MB of text in a few KB: past Pillow's 1 MB limit
    rgb = text / json.loads((text / "transforms.json").read_text())["frames"][0]["file_path"]
    Image.open(rgb).convert("RGB").save(rgb, pnginfo=info)
    # encode: a robot-style test scene with its edits/ folders, a link to /, a lying .npz in --out
    enc = _scene_copy(scene, w / "enc" / "test" / "scene_00000")
    shutil.copytree(scene, enc / "edits" / "move")
    (w / "enc" / "test" / "root").symlink_to("/", target_is_directory=True)
    (w / "npz_out").mkdir()
    lying_npz(w / "npz_out" / "scene.npz")
    big_gaussians_ply(w / "big.ply")


def _refusals(x: dict[str, Path]) -> dict[str, tuple]:
    """name -> (arguments, the words the one line must hold[, the case's other keys: entry, env])."""
    w, scene, good, data = x["w"], x["scene"], str(x["good"]), x["data"]
    train = ["train", "--config", str(x["cfg"]), "--data", str(data)]
    curve = lambda name: ["curve", str(w / "logs" / name), "--out", str(w / "c.png")]  # noqa: E731
    shown = ["--checkpoint", good, "--scene", str(scene)]  # the viewer opened on a model scene
    viewer = {"entry": VIEWER}

    def panel(request: str, value: Path | str, line: str, env: dict | None = None) -> tuple:
        """A panel request of the viewer opened on ``shown`` (its status line printed on stderr)."""
        argv = ["viewer_panel:panel", request, str(value), *shown, "--output-dir", str(w / "viewer_out")]
        return argv, line, {"entry": "call", "env": env}

    wide = str(w / "wide.pt")
    wide_keys = r"\(model.resolution 32, model.particles_per_view 3, model.patch_gaussians 16, model.refine_scale 1\)"
    wide_pass = r": a render pass of 2 views of 32x32, [\d,]+ Gaussians .*covering [\d,]+ \(tile, Gaussian\) pairs: "
    return {
        # the viewer's outputs: --screenshot refused before the display opens; the panel's on its status line
        "viewer --screenshot over its checkpoint": (
            [*shown, "--frames", "1", "--screenshot", good],
            r"--screenshot \S+good.pt: is --checkpoint \S+good.pt, which this command reads",
            viewer,
        ),
        "viewer --screenshot over a scene image": (
            [*shown, "--frames", "1", "--screenshot", str(x["rgb"])],
            r"--screenshot \S+png: would replace a file inside --scene \S+scene, which this command reads",
            viewer,
        ),
        "viewer --screenshot over its .ply": (
            ["--ply", str(w / "big.ply"), "--frames", "1", "--screenshot", str(w / "big.ply")],
            r"--screenshot \S+big.ply: is --ply \S+big.ply",
            viewer,
        ),
        "viewer --screenshot into a locked run": (
            [*shown, "--frames", "1", "--screenshot", str(w / "locked_run" / "shot.png")],
            rf"--screenshot \S+shot.png: lies in the run folder \S+locked_run, in use by process {os.getpid()}",
            viewer,
        ),
        "viewer panel, a screenshot into a locked run": panel(
            "screenshot",
            w / "locked_run",
            r"^error: screenshot \S+locked_run/particlesplat_0001.png: lies in the run folder \S+locked_run, in use",
        ),
        "viewer panel, an export into a locked run": panel(
            "export",
            w / "locked_run",
            r"^error: export \S+locked_run/particlesplat_0001.ply: lies in the run folder \S+locked_run, in use",
        ),
        "viewer panel, Save edits over its checkpoint twice": panel(
            "save",
            good,
            r"^error: edits file \S+good.pt: is --checkpoint \S+good.pt, which this command reads",
        ),
        "viewer panel, Save edits over the scene's transforms.json": panel(
            "save",
            scene / "transforms.json",
            r"^error: edits file \S+transforms.json: would replace a file inside --scene \S+scene",
        ),
        "viewer panel, opening a scene with the autosave folder in a locked run": panel(
            "open",
            scene,
            r"^error: autosave \S+locked_run/state/particlesplat/autosave/\S+.edits.yaml: lies in the run folder "
            r"\S+locked_run, in use by .*; \S+scene not opened: save the edits elsewhere",
            {"XDG_STATE_HOME": str(w / "locked_run" / "state")},
        ),
        # the benchmarks' --json goes through the same guard, the default model included
        "bench formats --json over its checkpoint": (
            ["bench", "formats", *shown, "--json", good],
            r"--json \S+good.pt: is --checkpoint \S+good.pt, which this command reads",
        ),
        "bench formats --json over its .ply": (
            ["bench", "formats", "--ply", str(w / "big.ply"), "--json", str(w / "big.ply")],
            r"--json \S+big.ply: is --ply \S+big.ply, which this command reads",
        ),
        # render passes priced from their tile pairs where the Gaussians are the model's
        "eval, render passes past the limit": (
            ["eval", "--checkpoint", wide, "--data", str(w / "split")],
            wide_keys + wide_pass,
            {"env": WIDE_LIMIT},
        ),
        "encode, the refinement's render pass past the limit": (
            ["encode", "--checkpoint", wide, "--data", str(scene), "--out", str(w / "wide_enc"), "--no-progress"],
            wide_keys + wide_pass,
            {"env": WIDE_LIMIT},
        ),
        "train --overwrite, a step's render pass past the limit": (
            ["train", "--config", str(w / "wide.yaml"), "--data", str(data), "--out", str(w / "wide_run")]
            + ["--overwrite"],
            r"wide.yaml: a training step renders 2 scene\(s\) x 3 views \(train.batch_size 2; 2 context \+ "
            r"train.target_views 1\) at 32x32 with gradients \(model.resolution 32, train.particles_per_view 4, "
            r"model.patch_gaussians 16, .*\): [\d,]+ Gaussians a scene .* covering [\d,]+ \(tile, Gaussian\) pairs: "
            r"needs about .* more than the memory limit of 24.0 MiB",
            {"env": WIDE_LIMIT},
        ),
        # outputs never replace an input, nor a file of a locked run
        "curve --out its own log": (
            ["curve", str(w / "run"), "--out", str(w / "run" / "metrics.jsonl")],
            r"--out \S+run/metrics.jsonl: is RUN \S+run/metrics.jsonl, which this command reads",
        ),
        "eval --json over the scene's transforms.json": (
            ["eval", "--checkpoint", good, "--data", str(w / "split"), "--json", str(scene / "transforms.json")],
            r"--json \S+transforms.json: would replace a file inside --data \S+split, which this command reads",
        ),
        "render --out over an input image": (
            ["render", "--checkpoint", good, "--scene", str(scene), "--out", str(x["rgb"])],
            r"--out \S+: would replace a file inside --scene \S+scene, which this command reads",
        ),
        "render --out its own checkpoint": (
            ["render", "--checkpoint", good, "--scene", str(scene), "--out", good],
            r"--out \S+good.pt: is --checkpoint \S+good.pt",
        ),
        "model set --out into a locked run": (
            ["model", "set", good, "refine_scale=0.5", "--out", str(w / "locked_run" / "last.pt")],
            rf"--out \S+last.pt: lies in the run folder \S+locked_run, in use by process {os.getpid()}",
        ),
        "train --overwrite of the run holding --init": (
            train + ["--init", str(w / "init_run" / "best.pt"), "--out", str(w / "init_run"), "--overwrite"],
            r"--out \S+init_run: holds --init \S+best.pt, which this command reads, and its contents are replaced",
        ),
        # runs
        "--stop-after 0": (train + ["--out", str(w / "new_run"), "--stop-after", "0"], r"--stop-after must be >= 1"),
        "--resume of a run without a checkpoint": (
            train + ["--out", str(w / "unstarted"), "--resume"],
            r"last.pt: nothing to resume: the run stopped before its first checkpoint .* --overwrite",
        ),
        "--resume with another train.batch_size": (
            [
                "train",
                "--config",
                str(w / "other_batch.yaml"),
                "--data",
                str(data),
                "--out",
                str(w / "run"),
                "--resume",
            ],
            r"last.pt: train.batch_size: the run was started with 2, --config \S+other_batch.yaml gives 1",
        ),
        # logs read by the validating reader
        "curve, a psnr of text": (curve("psnr_text"), r"metrics.jsonl: line 1: key 'val.psnr' must be a number"),
        "curve, a NaN step": (curve("step_nan"), r"metrics.jsonl: line 1: key 'step' must be a non-negative integer"),
        "curve, a val record without step": (curve("no_step"), r"metrics.jsonl: line 1: a 'val' record without"),
        "curve, invalid UTF-8": (curve("utf8"), r"metrics.jsonl: line 1: not a JSON object"),
        "curve, deep nesting": (curve("nested"), r"metrics.jsonl: line 1: not a JSON object \(nested too deeply\)"),
        # checkpoints: every field checked, weights in float32's range
        "a provenance of the wrong type, model info": (
            ["model", "info", str(w / "prov.pt")],
            r"prov.pt: provenance.wall_hours: expected a finite non-negative number",
        ),
        "a train section of the wrong type, eval": (
            ["eval", "--checkpoint", str(w / "train.pt"), "--data", str(w / "split")],
            r"train.pt: train.*batch_size",
        ),
        "weights x 1e30, render": (
            ["render", "--checkpoint", str(w / "huge.pt"), "--scene", str(scene), "--out", str(w / "o.png")],
            r"huge.pt: state_dict\.\S+: values up to \S+, beyond the \+-1e\+06",
        ),
        "weights stored as int64, render": (
            ["render", "--checkpoint", str(w / "int.pt"), "--scene", str(scene), "--out", str(w / "o.png")],
            r"int.pt: state_dict\.\S+: stored as torch.int64, but the model's weight is floating-point",
        ),
        # family: named, never guessed
        "an unknown family, eval": (
            ["eval", "--data", str(w / "family" / "drone")],
            r"drone/s/scene.json: key 'family' is 'drone', not one of tabletop, robot",
        ),
        "a family of 123, encode": (
            ["encode", "--data", str(w / "family" / "number"), "--out", str(w / "fam_out")],
            r"number/s/scene.json: key 'family' is 123, not one of",
        ),
        "a folder of two families, eval": (
            ["eval", "--data", str(w / "family" / "mixed")],
            r"mixed: mixes scene families \(\S+ is robot, \S+ is tabletop\)",
        ),
        "insert across families": (
            ["object", "insert", "--scene", str(TAB0), "--from", str(ROB0), "--object", "0", "--out", str(w / "i.ply")],
            r"--from \S+ is a robot scene and --scene \S+ a tabletop scene",
        ),
        # robot inputs beyond the joint limits
        "a pose of 100 rad, render": (
            ["render", "--scene", str(w / "robot" / "rad100"), "--out", str(w / "o.png")],
            r"rad100/scene.json: key 'arm_joints_rad'\[0\] is 100 rad, beyond the joint's limits",
        ),
        # numbers in float32's plausible ranges
        "depths of 1e17 x 16-bit units, render": (
            ["render", "--checkpoint", good, "--scene", str(w / "numbers" / "depth"), "--out", str(w / "o.png")],
            r"key 'depth_file_path': \S+ has depths up to \S+ m .*beyond the 100000 m a depth may hold",
        ),
        "poses at ECEF scale, render": (
            ["render", "--checkpoint", good, "--scene", str(w / "numbers" / "ecef"), "--out", str(w / "o.png")],
            r"frames\[0\]: key 'transform_matrix' puts the camera 4.2e\+06 m from the origin",
        ),
        "a framing distance of 1e-300, render": (
            ["render", "--checkpoint", good, "--scene", str(w / "numbers" / "distance"), "--out", str(w / "o.png")],
            r"distance/scene.json: key 'distance' must be a number of metres in",
        ),
        "a NaN true centre, eval": (
            ["eval", "--checkpoint", good, "--data", str(w / "centre")],
            r"scene.json: objects\[0\].center must be 3 finite metres",
        ),
        "--at 1e300,0, object insert": (
            ["object", "insert", "--checkpoint", good, "--scene", str(scene), "--from", str(scene), "--object", "0"]
            + ["--at", "1e300,0", "--out", str(w / "i.ply")],
            r"--at: X,Y must be finite metres within",
        ),
        "a .ply that covers every tile at 2048^2, render": (
            ["render", "--ply", str(w / "big.ply"), "--width", "2048", "--height", "2048", "--out", str(w / "o.png")],
            r"big.ply: 20,000 Gaussians covering [\d,]+ \(tile, Gaussian\) pairs at 2048x2048: needs about "
            ".* more than the memory",
        ),
        "render --prune nan": (
            ["render", "--checkpoint", good, "--scene", str(scene), "--prune", "nan", "--out", str(w / "o.png")],
            r"--prune must be in \[0, 1\], got nan",
        ),
        "eval --z-t-threshold nan": (
            ["eval", "--checkpoint", good, "--data", str(w / "split"), "--z-t-threshold", "nan"],
            r"--z-t-threshold must be in \[0, 1\], got nan",
        ),
        "eval --fit-lr 1e300": (
            ["eval", "--checkpoint", good, "--data", str(w / "split"), "--fit-steps", "2", "--fit-lr", "1e300"],
            r"--fit-lr must be in \(0, 10\], got 1e\+300",
        ),
        "bench render --n 1e9": (
            ["bench", "render", "--n", "1000000000", "--sizes", "64"],
            r"--n 1000000000 --sizes 64: 1,000,000,000 Gaussians rendered forward and backward at 64x64: needs",
        ),
        "bench edits --start -100": (["bench", "edits", "--start", "-100"], r"--start must be >= 0"),
        "bench edits --dilate -1": (["bench", "edits", "--dilate", "-1"], r"--dilate must be in \[0, 64\]"),
        # scene check on what its reader did not see
        "scene check, every camera at one point": (
            ["scene", "check", str(w / "rig" / "point")],
            r"point/transforms.json: the cameras stand where they look",
        ),
        "scene check --write, a depth scale that is text": (
            ["scene", "check", str(w / "rig" / "scale"), "--write", str(w / "t.json")],
            r"scale/transforms.json: key 'depth_unit_scale_factor' is not a number",
        ),
        # readers: every JSON through the checked reader, PNG text chunks
        "a 17 MB scene.json, eval --checkpoint": (
            ["eval", "--checkpoint", good, "--data", str(w / "readers" / "big")],
            r"big/s/scene.json: more than the 16,777,216 bytes a scene.json may have",
        ),
        "a deeply nested scene.json, eval --checkpoint": (
            ["eval", "--checkpoint", good, "--data", str(w / "readers" / "nested")],
            r"nested/s/scene.json: not valid JSON \(nested too deeply\)",
        ),
        "a PNG text chunk past Pillow's limit, eval": (
            ["eval", "--checkpoint", good, "--data", str(w / "readers" / "text")],
            r"frames\[0\]: key 'file_path': cannot read image \S+ \(Decompressed data too large",
        ),
        "an --init checkpoint of 8.6 GB of weights": (
            ["train", "--init", str(w / "big_init.pt"), "--data", str(data), "--out", str(w / "big_init_run")],
            r"--init \S+big_init.pt: model: a model of [\d,]+ weights",
        ),
        # messages name the file or flag at fault
        "model set of a checkpoint whose weights do not fit its config": (
            ["model", "set", str(w / "mismatch.pt"), "refine_scale=0.5", "--out", str(w / "m_out.pt")],
            r"mismatch.pt with refine_scale: state_dict does not match its config",
        ),
        "bench train --run of a diverged run": (
            ["bench", "train", "--data", str(data), "--run", str(w / "nan_bench_run"), "--threads", "1"]
            + ["--steps", "1", "--warmup", "0"],
            r"nan_bench_run/last.pt: state_dict\.\S+: non-finite weights",
        ),
        # synth owns its folder and keeps one family
        "synth into a folder another synth holds": (
            ["synth", str(w / "synth_locked"), "--train", "1", "--val", "0", "--test", "0", "--res", "16"],
            rf"synth_locked: in use by process {os.getpid()}",
        ),
        "tabletop synth into a robot folder": (
            ["synth", str(w / "synth_mixed"), "--train", "1", "--val", "0", "--test", "0", "--res", "16"],
            r"scene_00000/scene.json: key 'generator' is 'particlesplat.data.families.robot' but this run uses",
        ),
    }


def _successes(x: dict[str, Path]) -> dict[str, tuple[list[str], str | None]]:
    """name -> (arguments, a line stderr must hold, or None); each must exit 0 within the cap."""
    w, data = x["w"], x["data"]
    return {
        "curve, null and inf metrics": (["curve", str(w / "logs" / "odd"), "--out", str(w / "odd.png")], None),
        "curve, a 150 MB log": (["curve", str(w / "logs" / "big"), "--out", str(w / "big.png")], None),
        "train.num_threads 1024": (
            ["train", "--config", str(w / "threads.yaml"), "--data", str(data), "--out", str(w / "threads_run")],
            r"warning: train.num_threads: 1024 threads on \d+ usable cores; using \d+",
        ),
        "bench encode --threads 5000": (
            ["bench", "encode", "--checkpoint", str(x["good"]), "--data", str(w / "split"), "--threads", "5000"]
            + ["--scenes", "1", "--rounds", "1"],
            r"warning: --threads: 5000 threads on \d+ usable cores",
        ),
        "--overwrite of a run without a checkpoint": (
            ["train", "--config", str(x["cfg"]), "--data", str(data), "--out", str(w / "unstarted"), "--overwrite"]
            + ["--stop-after", "1"],
            None,
        ),
        "a joint outside the trained range, render": (
            ["render", "--scene", str(w / "robot" / "plus06"), "--width", "32", "--height", "24"]
            + ["--out", str(w / "plus06.png")],
            None,  # the robot model reads the arm by exact kinematics: a pose it never saw is no reason to warn
        ),
        "a framing far from the cameras, render": (
            ["render", "--checkpoint", str(x["good"]), "--scene", str(w / "numbers" / "far_framing"), "--width", "32"]
            + ["--height", "24", "--out", str(w / "far.png")],
            r"warning: \S+far_framing/scene.json: look_at 50,50,0 and distance 1 m frame a point \S+ m from where",
        ),
        "encode a test split with edits/ and a link to /": (
            ["encode", "--checkpoint", str(x["good"]), "--data", str(w / "enc"), "--out", str(w / "enc_out")],
            r"test/root: a symbolic link to /, outside \S+ and not a scene folder; left out",
        ),
        "encode over an .npz with a lying header": (
            ["encode", "--checkpoint", str(x["good"]), "--data", str(x["scene"]), "--out", str(w / "npz_out")],
            None,
        ),
        "--resume without config.yaml": (
            ["train", "--data", str(data), "--out", str(w / "no_config_run"), "--resume", "--stop-after", "1"],
            r"the config stored in \S+no_config_run/last.pt",
        ),
    }


@pytest.fixture(scope="module")
def results(world, tmp_path_factory):
    refusals, successes = _refusals(world), _successes(world)
    specs = [
        {"entry": PS, "argv": c[0], "cap_mb": CAP_MB, "timeout": 120, "watch": [str(world["w"])], **dict(*c[2:])}
        for c in refusals.values()
    ] + [{"entry": PS, "argv": argv, "cap_mb": CAP_MB, "timeout": 300} for argv, _ in successes.values()]
    io = tmp_path_factory.mktemp("runner")
    (io / "cases.json").write_text(json.dumps(specs))
    proc = subprocess.run(
        [sys.executable, str(HERE / "runner.py"), str(io / "cases.json"), str(io / "out.json")],
        capture_output=True,
        text=True,
        timeout=1500,
        cwd=io,  # nothing is written into the working directory
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parent.parent), os.environ.get("PYTHONPATH", "")])},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads((io / "out.json").read_text())
    assert sorted(p.name for p in io.iterdir()) == ["cases.json", "out.json"]
    names = [*refusals, *successes]
    if os.environ.get("HOSTILE_REPORT"):  # per case: exit code, seconds, peak RSS
        rows = [
            {"case": n, "code": r["code"], "seconds": round(r["seconds"], 3), "max_rss_mb": round(r["max_rss_mb"])}
            for n, r in zip(names, res, strict=True)
        ]
        Path(os.environ["HOSTILE_REPORT"]).write_text(json.dumps(rows, indent=1))
    return dict(zip(names, res, strict=True))


def _names(kind) -> list[str]:
    return list(kind({k: Path(k) for k in ("w", "data", "scene", "cfg", "good", "rgb")}).keys())


@pytest.mark.parametrize("name", _names(_refusals))
def test_case_is_one_line_exit_2_nothing_changed(results, world, name):
    res = results[name]
    lines = [x for x in _lines(res["stderr"]) if not x.startswith("--init without --config:")]  # where from
    assert not res["timed_out"] and res["code"] == 2, res["stderr"][-3000:]
    assert len(lines) == 1 and "Traceback" not in res["stderr"], res["stderr"][-3000:]
    assert re.search(_refusals(world)[name][1], lines[0]), lines[0]
    assert res["changed"] == [], res["changed"]


@pytest.mark.parametrize("name", _names(_successes))
def test_case_succeeds_within_the_cap(results, world, name):
    res = results[name]
    assert not res["timed_out"] and res["code"] == 0, res["stderr"][-3000:]
    assert "Traceback" not in res["stderr"], res["stderr"][-3000:]
    want = _successes(world)[name][1]
    if want:
        assert re.search(want, res["stderr"]), res["stderr"][-2000:]
    if name.startswith("a joint outside"):
        assert "the model was trained" not in res["stderr"], res["stderr"][-2000:]
    if name.startswith("encode a test split"):  # one scene: neither its edits/ nor the machine behind the link
        assert sorted(p.name for p in (world["w"] / "enc_out").rglob("*.npz")) == ["scene_00000.npz"]
    if name.startswith("encode over an .npz"):
        assert "1 of them over a stale file" in res["stdout"], res["stdout"]


def _tree(folder: Path) -> dict[str, float]:
    return {str(p): p.stat().st_mtime for p in folder.rglob("*")} if folder.is_dir() else {}


def test_synth_sigterm_stops_its_pool_and_keeps_finished_scenes(tmp_path):
    """SIGTERM to ``synth`` is Ctrl-C: one line, exit 143, the worker pool gone with the command (nothing is
    written after it returns), finished scenes kept and the folder's lock given back."""
    out = tmp_path / "data"
    cmd = [sys.executable, "-m", "particlesplat.cli", "synth", str(out), "--train", "60", "--val", "0", "--test", "0"]
    proc = subprocess.Popen(
        cmd + ["--res", "32", "--workers", "2"],
        cwd=HERE.parent.parent,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not list((out / "train").glob("scene_*")) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert list((out / "train").glob("scene_*")), "no scene finished in 120 s"
        proc.send_signal(signal.SIGTERM)  # the command only, as a service manager or `kill PID` does
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    lines = [x for x in err.replace("\r", "\n").splitlines() if x.strip() and not x.startswith("synth")]
    assert lines == [
        f"particlesplat synth: interrupted (finished scenes are kept in {out}; run the same command again to resume)"
    ], err[-2000:]
    time.sleep(0.5)
    with pytest.raises(ProcessLookupError):  # no worker outlived the command
        os.killpg(proc.pid, 0)
    before = _tree(out)
    time.sleep(1.0)
    assert _tree(out) == before
    assert not (out / ".lock").exists()


def test_scene_check_write_over_transforms_keeps_the_original(world, tmp_path):
    from particlesplat.cli.main import main

    scene = tmp_path / "scene"
    shutil.copytree(world["scene"], scene)
    original = (scene / "transforms.json").read_bytes()
    for _ in (1, 2):
        assert main(["scene", "check", str(scene), "--write", str(scene / "transforms.json")]) in (0, 1)
    assert (scene / "transforms.json.orig").read_bytes() == original  # the first original, never replaced
    assert (scene / "transforms.json.orig-2").is_file()
    json.loads((scene / "transforms.json").read_text())


def test_bench_edits_writes_no_file_it_was_not_given(world, tmp_path):
    """No default output in the working directory; with --json, the file records the model that ran."""
    env = {**os.environ, "PYTHONPATH": str(HERE.parent.parent), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "particlesplat.cli", "bench", "edits", "--checkpoint", str(world["good"])]
    cmd += ["--scenes", "1", "--res", "32", "--work", str(tmp_path / "work")]
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert list(cwd.iterdir()) == []
    proc = subprocess.run(cmd + ["--json", "b.json"], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((cwd / "b.json").read_text())["checkpoint"] == str(world["good"])


def test_the_scene_cache_is_bounded_in_bytes(world):
    """The training cache holds at most its share of the memory limit: scenes past it are read again."""
    from particlesplat.data import SceneDataset
    from particlesplat.data.scene import read_scene

    ds = SceneDataset(world["data"] / "train", cache_size=100)
    sizes = [sum(a.nbytes for a in (*r.rgb, *r.depth, *r.masks) if a is not None) for r in map(read_scene, ds.scenes)]
    ds = SceneDataset(world["data"] / "train", cache_size=100, cache_bytes=max(sizes) + 1)
    for i in range(len(ds)):
        ds.raw(i)
    assert len(ds._cache) == 1 and ds._cached_bytes == sizes[-1] <= ds.cache_bytes
    ds = SceneDataset(world["data"] / "train", cache_size=100, cache_bytes=min(sizes) - 1)
    ds.raw(0)
    assert len(ds._cache) == 0 and ds._cached_bytes == 0


def test_non_finite_gaussians_in_training_skip_the_step(world, tmp_path, monkeypatch):
    """A forward pass whose Gaussians the renderer refuses (a learning rate too high) is a skipped step, as a
    non-finite loss is: the weights do not move."""
    import particlesplat.training.trainer as trainer_module
    from particlesplat.core.gaussians import BadGaussiansError
    from particlesplat.model import load_config

    cfg, tc = load_config(world["cfg"])
    trainer = trainer_module.Trainer(cfg, tc, world["data"], tmp_path / "run", "cpu", resume=False)
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}

    def diverged(*args, **kwargs):
        raise BadGaussiansError("render: means: non-finite value at Gaussian 3")

    monkeypatch.setattr(trainer_module, "training_loss", diverged)
    try:
        assert trainer.train_step() == {"skipped": 1.0}
    finally:
        trainer.lock.release()
    assert trainer.step == 1
    assert all(torch.equal(before[k], v) for k, v in trainer.model.state_dict().items())


def test_resume_takes_a_new_length_with_a_warning(world, tmp_path, capsys):
    """``steps`` (and the reporting keys) may change on --resume, with a warning naming the old and new value."""
    from particlesplat.cli.main import main

    run = tmp_path / "run"
    shutil.copytree(world["w"] / "run", run)
    longer = yaml.safe_load(world["cfg"].read_text())
    longer["train"]["steps"] = 5
    (tmp_path / "longer.yaml").write_text(yaml.safe_dump(longer))
    argv = ["train", "--config", str(tmp_path / "longer.yaml"), "--data", str(world["data"]), "--out", str(run)]
    assert main([*argv, "--resume", "--stop-after", "1"]) == 0
    assert "train: resumed with steps 4 -> 5 (the learning-rate schedule follows the new steps)" in (
        capsys.readouterr().err
    )


def test_thread_variables_past_the_cores_are_lowered(world, tmp_path):
    """OMP_NUM_THREADS=5000 is lowered to the cores before torch reads it, with a warning."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "5000"}
    cmd = [
        sys.executable,
        "-m",
        "particlesplat.cli",
        "curve",
        str(world["w"] / "run"),
        "--out",
        str(tmp_path / "c.png"),
    ]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert re.search(r"warning: OMP_NUM_THREADS=5000: \d+ usable cores; using \d+", proc.stderr), proc.stderr


def test_scene_check_write_over_another_input_file_is_refused(world, tmp_path):
    from particlesplat.cli.main import main
    from particlesplat.core.outputs import OutputError

    scene = tmp_path / "scene"
    shutil.copytree(world["scene"], scene)
    image = scene / json.loads((scene / "transforms.json").read_text())["frames"][0]["file_path"]
    before = image.read_bytes()
    with pytest.raises(OutputError, match=r"--write \S+: would replace a file inside DIR"):
        main(["scene", "check", str(scene), "--write", str(image)])
    assert image.read_bytes() == before
