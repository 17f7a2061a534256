"""Hostile and broken input, case by case where it is handled: YAML, .ply, images, outputs,
the renderer's edge, edits. Each test builds the bad input and checks the one error that names the file
and the field (or, for outputs, that nothing was replaced)."""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from particlesplat import Gaussians
from particlesplat.core.atomic import UnsafeTargetError, atomic_path, atomic_write, check_writable
from particlesplat.core.errors import short_repr
from particlesplat.core.gaussians import MAX_OWNER
from particlesplat.core.yamlsafe import MAX_YAML_BYTES, YamlError, load_yaml
from particlesplat.data.scene import MAX_IMAGE_PIXELS, SceneFormatError, read_scene
from particlesplat.data.synth import write_scene
from particlesplat.editing.editor import load_edit_file
from particlesplat.editing.particle_edits import EditsError, validate_edits
from particlesplat.formats.ply import PlyError

ALIAS_BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, "
    f"*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}]\n"
    for i in range(8)
)


def _gaussians(n: int = 5, owner=None) -> Gaussians:
    g = Gaussians(
        torch.randn(n, 3),
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), 0.1),
        torch.full((n,), 0.5),
        torch.zeros(n, 1, 3),
        torch.zeros(n, dtype=torch.int64),
    )
    if owner is not None:
        g.owner = torch.as_tensor(owner, dtype=torch.int64)
    return g


# ---------------------------------------------------------------------------- YAML
def test_alias_bomb_is_refused_before_expansion():
    assert len(ALIAS_BOMB) < 600  # 9**9 = 387 million leaves once expanded
    with pytest.raises(YamlError, match=r"bomb\.yaml: not valid YAML \(line 2, column \d+: alias '\*a' is not allowed"):
        load_yaml(ALIAS_BOMB, "bomb.yaml")


def test_duplicate_keys_are_refused_with_their_line():
    with pytest.raises(YamlError, match=r"c\.yaml: not valid YAML \(line 3, column 1: key 'lr' is given twice\)"):
        load_yaml("lr: 1.0\nsteps: 3\nlr: 2.0\n", "c.yaml")


def test_exponent_without_dot_is_a_float():
    assert load_yaml("lr: 1e-4\nb: -2E+3\nc: 10\nd: '1e-4'\n", "x") == {"lr": 1e-4, "b": -2000.0, "c": 10, "d": "1e-4"}


def test_oversized_deep_and_python_tagged_yaml_are_one_line_errors():
    for text in (
        "x" * (MAX_YAML_BYTES + 1),
        "[" * 5000 + "]" * 5000,
        "a: !!python/object/apply:os.system [ls]",
        "a: " + "9" * 5000,
    ):
        with pytest.raises(YamlError) as info:
            load_yaml(text, "f.yaml")
        assert str(info.value).startswith("f.yaml: ") and "\n" not in str(info.value) and len(str(info.value)) < 400


def test_short_repr_does_not_expand_shared_structures():
    leaf = ["x" * 10] * 10
    for _ in range(8):
        leaf = [leaf] * 10  # 10**9 leaves if printed in full
    text = short_repr(leaf)
    assert len(text) <= 80 and text.endswith("...")
    assert short_repr({"a": 1}) == "{'a': 1}"


def test_edits_file_alias_bomb_and_duplicates_name_the_file(tmp_path):
    p = tmp_path / "e.yaml"
    p.write_text("particles:\n  0: &v {z_t: [0.5]}\n  1: *v\n")
    with pytest.raises(EditsError, match=r"e\.yaml: not valid YAML \(line 3.*alias"):
        load_edit_file(p)
    p.write_text("particles:\n  0: {z_t: [0.5]}\n  0: {z_t: [0.2]}\n")
    with pytest.raises(EditsError, match=r"e\.yaml: not valid YAML \(line 3.*given twice"):
        load_edit_file(p)


def test_edit_value_beyond_float32_is_refused():
    assert validate_edits({1: {"z_d": [3.0e38]}}) == {1: {"z_d": (3.0e38,)}}
    with pytest.raises(EditsError, match=r"particles\.1\.z_d: 1e\+300 is beyond float32"):
        validate_edits({1: {"z_d": [1e300]}})


def test_edit_error_does_not_echo_a_long_value():
    with pytest.raises(EditsError) as info:
        validate_edits({1: {"z_p": ["y" * 100000, 1.0]}})
    assert len(str(info.value)) < 300


# ---------------------------------------------------------------------------- .ply
def _ply_bytes(n_declared: int, rows: np.ndarray, extra_header: str = "") -> bytes:
    names = rows.dtype.names
    types = {"<f4": "float", "<i4": "int", "<f8": "double"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n_declared}"]
    header += [f"property {types[rows.dtype[n].str]} {n}" for n in names]
    return ("\n".join(header) + "\n" + extra_header + "end_header\n").encode() + rows.tobytes()


def _rows(n: int, owner_dtype: str = "<i4") -> np.ndarray:
    names = [
        "x",
        "y",
        "z",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    rec = np.zeros(n, dtype=np.dtype([(k, "<f4") for k in names] + [("owner", owner_dtype)]))
    rec["rot_0"] = 1.0
    return rec


@pytest.mark.parametrize(
    "owner, dtype", [(2147483647, "<i4"), (-5, "<i4"), (float("nan"), "<f4"), (2.5, "<f4"), (MAX_OWNER + 1, "<i4")]
)
def test_ply_owner_outside_the_particle_range_is_refused(tmp_path, owner, dtype):
    rows = _rows(3, dtype)
    rows["owner"][1] = owner
    (tmp_path / "o.ply").write_bytes(_ply_bytes(3, rows))
    with pytest.raises(
        PlyError,
        match=r"o\.ply: property 'owner' at vertex 1 is .*expected -1 \(background\) or a "
        rf"particle index 0\.\.{MAX_OWNER}",
    ):
        Gaussians.load_ply(tmp_path / "o.ply")


def test_ply_owner_in_range_round_trips(tmp_path):
    rows = _rows(3)
    rows["owner"] = [-1, 0, MAX_OWNER]
    (tmp_path / "o.ply").write_bytes(_ply_bytes(3, rows))
    assert Gaussians.load_ply(tmp_path / "o.ply").owner.tolist() == [-1, 0, MAX_OWNER]


def test_ply_vertex_count_is_checked_against_the_file_size(tmp_path):
    (tmp_path / "lie.ply").write_bytes(_ply_bytes(10**9, _rows(4)))
    with pytest.raises(
        PlyError,
        match=r"lie\.ply: truncated: header declares 1000000000 vertices .* file holds 240 "
        r"bytes \(vertex 4, property 'x' onwards missing\)",
    ):
        Gaussians.load_ply(tmp_path / "lie.ply")


def test_ply_header_without_end_and_without_newline_is_bounded(tmp_path):
    (tmp_path / "h.ply").write_bytes(b"ply\n" + b"comment " + b"x" * 200000)
    with pytest.raises(PlyError, match=r"h\.ply: header longer than"):
        Gaussians.load_ply(tmp_path / "h.ply")
    (tmp_path / "d.ply").write_bytes(_ply_bytes(1, _rows(1), "property float x\n"))
    with pytest.raises(PlyError, match=r"d\.ply: property 'x' is declared twice"):
        Gaussians.load_ply(tmp_path / "d.ply")


# ---------------------------------------------------------------------------- the renderer's edge
@pytest.mark.parametrize(
    "field, value, message",
    [
        ("sh", float("nan"), "sh: non-finite value at Gaussian 2"),
        ("quats", float("inf"), "quats: non-finite value at Gaussian 2"),
        ("quats", float("nan"), "quats: non-finite value at Gaussian 2"),
        ("scales", float("nan"), "scales: non-finite value at Gaussian 2"),
        ("scales", -1.0, "scales: negative value at Gaussian 2"),
        ("means", float("inf"), "means: non-finite value at Gaussian 2"),
    ],
)
def test_render_refuses_non_finite_gaussians(field, value, message):
    from particlesplat import render
    from particlesplat.core.viewpoints import default_view

    g = _gaussians()
    getattr(g, field)[2].view(-1)[0] = value
    cam = default_view(None, _gaussians()).camera(16, 12)
    with pytest.raises(ValueError, match=f"render: {message}"):
        render(g, cam)


def test_render_refuses_owner_outside_range():
    from particlesplat import render
    from particlesplat.core.viewpoints import default_view

    g = _gaussians(owner=[0, -7, 1, 2, 3])
    with pytest.raises(ValueError, match=r"render: owner: -7 at Gaussian 1 is neither -1"):
        render(g, default_view(None, g).camera(8, 8))


# ---------------------------------------------------------------------------- outputs
def test_atomic_writes_refuse_non_regular_targets(tmp_path):
    target = tmp_path / "real.txt"
    target.write_text("keep")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for path in (link, fifo, tmp_path, "/dev/null"):
        with pytest.raises(UnsafeTargetError, match=f"{path}: is a "), atomic_write(path, "w") as f:
            f.write("new")
        with pytest.raises(UnsafeTargetError, match=f"{path}: is a "), atomic_path(path) as p:
            p.write_text("new")
        with pytest.raises(UnsafeTargetError):
            check_writable(path)
    assert link.is_symlink() and target.read_text() == "keep" and os.path.exists("/dev/null")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "link.txt", "real.txt"]  # no temporary left


def test_check_writable_names_an_unwritable_folder(tmp_path):
    if os.geteuid() == 0:
        blocked = tmp_path / "file" / "x.json"  # a path under a regular file: no folder can be made there
        (tmp_path / "file").write_text("")
    else:
        (tmp_path / "ro").mkdir(mode=0o500)
        blocked = tmp_path / "ro" / "x.json"
    with pytest.raises(OSError, match=f"{blocked}: cannot write"):
        check_writable(blocked)
    assert check_writable(tmp_path / "new" / "ok.json") == tmp_path / "new" / "ok.json"
    assert not (tmp_path / "new").exists()  # nothing is created by the check


# ---------------------------------------------------------------------------- scene images
def _png_bomb(path, width: int, height: int) -> None:
    """A valid-looking grey PNG whose header declares width x height pixels (the data stream is tiny)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    raw = zlib.compress(b"\0" * (width + 1) * 4)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IDAT", raw)
        + chunk(b"IEND", b"")
    )


@pytest.fixture(scope="module")
def scene_template(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene") / "s"
    write_scene(folder, 0, "train", 0, 16)
    return folder


@pytest.fixture
def scene(scene_template, tmp_path):
    import shutil

    return Path(shutil.copytree(scene_template, tmp_path / "s"))


def _frames(scene):
    return json.loads((scene / "transforms.json").read_text())


def test_decompression_bomb_names_the_file_and_key(scene):
    meta = _frames(scene)
    image = scene / meta["frames"][1]["file_path"]
    for w, h in ((100000, 100000), (5000, 5000)):  # beyond PIL's own limit, and beyond ours only
        _png_bomb(image, w, h)
        assert w * h > MAX_IMAGE_PIXELS
        with pytest.raises(
            SceneFormatError,
            match=r"transforms\.json: frames\[1\]: key 'file_path': image .* "
            r"(declares more pixels|is \d+x\d+ pixels)",
        ):
            read_scene(scene)


def test_eight_bit_depth_is_an_error_naming_the_file(scene):
    meta = _frames(scene)
    depth = scene / meta["frames"][0]["depth_file_path"]
    a = np.asarray(Image.open(depth))
    Image.fromarray((a // 256).astype(np.uint8), "L").save(depth)
    with pytest.raises(SceneFormatError, match=rf"frames\[0\]: key 'depth_file_path': {depth} is an 8-bit image"):
        read_scene(scene)


@pytest.mark.parametrize("bad", ["/etc/hostname", "../outside.png", "rgb/../../outside.png"])
def test_scene_paths_stay_inside_the_folder(scene, bad):
    Image.new("RGB", (16, 16)).save(scene.parent / "outside.png")
    meta = _frames(scene)
    meta["frames"][2]["file_path"] = bad
    (scene / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(SceneFormatError, match=r"frames\[2\]: key 'file_path' names .* outside the scene folder"):
        read_scene(scene)


# ---------------------------------------------------------------------------- configs
@pytest.mark.parametrize(
    "key, value, message",
    [
        ("refine_hidden", 40000, r"refine\.hidden: must be in \[1, 4096\] \(got 40000\)"),
        ("resolution", 1048576, r"resolution: must be in \[16, 1024\]"),
        ("transformer_heads", 0, r"transformer\.heads: must be in \[1, 64\] \(got 0\)"),
        ("token_dim", -4, r"transformer\.token_dim: must be in \[1, 2048\] \(got -4\)"),
        ("d_max", float("inf"), r"d_max: must be a finite number \(got inf\)"),
        ("prior_depth_mean", float("nan"), r"prior\.depth_mean: must be a finite number \(got nan\)"),
    ],
)
def test_model_config_ranges_and_finite_values(key, value, message):
    from particlesplat.model.config import ConfigError, model_config_from_dict

    with pytest.raises(ConfigError, match=rf"^ckpt\.pt: config\.{message}"):
        model_config_from_dict({key: value}, "ckpt.pt: config")


def test_train_config_val_scenes_and_quoted_number():
    from particlesplat.model.config import ConfigError, train_config_from_dict

    with pytest.raises(ConfigError, match=r"train\.val_scenes: must be in \[1, 1000000\] \(got -1\)"):
        train_config_from_dict({"val_scenes": -1}, "c.yaml: train")
    with pytest.raises(
        ConfigError,
        match=r"train\.lr: expected float, got '1e-4' \(text, not a number: write it "
        r"without quotes, e\.g\. 1\.0e-4",
    ):
        train_config_from_dict({"lr": "1e-4"}, "c.yaml: train")


def test_config_file_alias_bomb_duplicate_key_and_unquoted_exponent(tmp_path):
    from particlesplat.model.config import ConfigError, load_config

    p = tmp_path / "c.yaml"
    p.write_text("model: {}\n" + ALIAS_BOMB)
    with pytest.raises(ConfigError, match=r"c\.yaml: not valid YAML \(line 3, column \d+: alias"):
        load_config(p)
    p.write_text("train:\n  lr: 0.1\n  lr: 0.2\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: not valid YAML \(line 3, column 3: key 'lr' is given twice"):
        load_config(p)
    p.write_text("train:\n  " + "k" * 100000 + ": 1\n")
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert len(str(info.value)) < 1500


# ---------------------------------------------------------------------------- checkpoints
@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    from model_data import TINY_MODEL

    from particlesplat.model import ParticleSplat, save_checkpoint
    from particlesplat.model.config import model_config_from_dict

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ckpt") / "m.pt"
    save_checkpoint(path, ParticleSplat(model_config_from_dict(TINY_MODEL)), 3)
    return path


def _tampered(tiny_ckpt, tmp_path, change) -> Path:
    ckpt = torch.load(tiny_ckpt, weights_only=True)
    change(ckpt)
    out = tmp_path / "bad.pt"
    torch.save(ckpt, out)
    return out


def test_checkpoint_round_trip_loads(tiny_ckpt):
    from particlesplat.model import load_model

    assert load_model(tiny_ckpt).config.resolution == 32


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda c: c["state_dict"].__setitem__(next(iter(c["state_dict"])), torch.full((2,), float("nan"))),
            r"bad\.pt: state_dict\.\S+: non-finite weights",
        ),
        (
            lambda c: c.__setitem__("state_dict", [1, 2]),
            r"bad\.pt: state_dict: expected a mapping of names to tensors, "
            r"got list",
        ),
        (lambda c: c["config"].__setitem__("resolution", 64), r"bad\.pt: config: changed after the weights were saved"),
        (lambda c: c.__setitem__("config", "x" * 1000), r"bad\.pt: config: expected a mapping, got str"),
    ],
)
def test_checkpoint_tampering_is_refused(tiny_ckpt, tmp_path, change, message):
    from particlesplat.model import load_model
    from particlesplat.model.io import CheckpointError

    with pytest.raises(CheckpointError, match=message):
        load_model(_tampered(tiny_ckpt, tmp_path, change))


def test_checkpoint_config_out_of_range_is_refused_before_building(tiny_ckpt, tmp_path):
    from particlesplat.model import load_model
    from particlesplat.model.config import ConfigError

    def change(c):
        c["config"]["refine"]["hidden"] = 40000
        c.pop("config_sha256")

    with pytest.raises(ConfigError, match=r"bad\.pt: config\.refine\.hidden: must be in \[1, 4096\]"):
        load_model(_tampered(tiny_ckpt, tmp_path, change))


def test_pickled_checkpoint_message_never_suggests_unsafe_loading(tmp_path):
    import argparse

    from particlesplat.model import load_model
    from particlesplat.model.io import CheckpointError

    torch.save({"config": argparse.Namespace(a=1), "state_dict": {}, "step": 0}, tmp_path / "p.pt")
    with pytest.raises(CheckpointError) as info:
        load_model(tmp_path / "p.pt")
    assert "p.pt: refused" in str(info.value) and "weights_only" not in str(info.value)
    (tmp_path / "junk.pt").write_bytes(b"PK\x03\x04" + os.urandom(100))
    with pytest.raises(CheckpointError, match=r"junk\.pt: not a readable checkpoint"):
        load_model(tmp_path / "junk.pt")


def test_edit_values_beyond_float64_or_float32_in_both_formats():
    from particlesplat.editing.editor import parse_edit_file

    with pytest.raises(EditsError, match=r"particles\.1\.z_d: expected finite numbers"):
        validate_edits({1: {"z_d": [10**400]}})  # an integer beyond float64: no OverflowError
    with pytest.raises(EditsError, match=r"e\.yaml: operations\[0\]: particles\.0\.z_d: 1e\+300 is beyond float32"):
        parse_edit_file({"version": 2, "operations": [{"particle": 0, "set": {"z_d": [1e300]}}]}, "e.yaml")
    with pytest.raises(
        EditsError,
        match=r"e\.yaml: operations\[0\]\.translate: expected 3 finite number\(s\) "
        r"\(float32",
    ):
        parse_edit_file(
            {"version": 2, "operations": [{"pick": {"frame": 0, "pixel": [1, 2]}, "translate": [1e300, 0, 0]}]},
            "e.yaml",
        )


def test_scene_path_of_a_megabyte_is_one_short_line(scene):
    meta = _frames(scene)
    meta["frames"][0]["file_path"] = "x" * 1_000_000
    (scene / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(SceneFormatError, match=r"frames\[0\]: key 'file_path' is a path of 1000000 characters") as e:
        read_scene(scene)
    assert len(str(e.value)) < 400
