"""Hostile input on the splat formats, bundles, ``export`` and the robot's scene keys, through the project's guards:
the output guard (``export`` over its inputs, into a locked run, over a bundle holding a user's file), the checked
JSON reader (zip members and manifests), one memory budget per job (readers reserve what headers say they will
hold, summed over a file's images, members and parts), decoded values held to float32 and the world, typed header
fields, the rigid-pose check of ``robot_base`` and SIGTERM. Each command runs in its own process under the memory
cap (``runner.py``); a refusal is one line naming the file and the field, exit 2, no traceback, nothing changed."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]

from format_files import (  # noqa: E402
    bundle_folder,
    compressed_ply_edited,
    sog_of_big_images,
    sog_rewritten,
    sparse,
    sparse_ply,
    unbundled_sog_with_sparse_member,
    vp8l_header,
    webp_image,
)
from formats_spec import random_gaussians  # noqa: E402
from hostile_files import edit_json, lock_run  # noqa: E402
from test_hostile_suite import CAP_MB, _lines  # noqa: E402

PS = "particlesplat"
ROOT = HERE.parent.parent
TAB0, ROB0 = ROOT / "assets" / "scenes" / "scene_00000", ROOT / "assets" / "robot" / "scenes" / "scene_00019"
GZIP_HEADER = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff"  # a gzip member's header: deflate blocks follow


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    """``in/``: the files the refusals read and must leave unchanged (watched); ``big/``: sparse files of gigabytes
    (not hashed); ``out/``: where the successes write."""
    from particlesplat.formats.splat_files import write_gaussians
    from particlesplat.formats.spz import write_spz

    w = tmp_path_factory.mktemp("formats")
    inp, big = w / "in", w / "big"
    for folder in (inp, big, w / "out"):
        folder.mkdir()
    g = random_gaussians(40, 0, seed=3)
    for suffix in (".ply", ".compressed.ply", ".splat", ".spz", ".sog"):
        write_gaussians(g, inp / f"g{suffix}")
    write_gaussians(random_gaussians(40, 1, seed=4), inp / "sh.sog")
    # outputs: a bundle, a bundle holding the user's notes, a locked run, a scene holding a .ply
    bundle_folder(inp / "bundle", [("particle_0.ply", 40), ("rest.ply", 40)], copy_of=inp / "g.ply")
    bundle_folder(inp / "user_bundle", [("particle_0.ply", 40)], copy_of=inp / "g.ply")
    (inp / "user_bundle" / "notes.txt").write_text("mine")
    (inp / "locked_run").mkdir()
    lock_run(inp / "locked_run", os.getpid())
    shutil.copytree(TAB0, inp / "scene")
    shutil.copy(inp / "g.ply", inp / "scene" / "points.ply")
    # JSON: nested and oversized, in a zip and in a bundle
    sog_rewritten(inp / "g.sog", inp / "nested.sog", meta_json=b"[" * 100_000 + b"]" * 100_000)
    sog_rewritten(inp / "g.sog", inp / "padded.sog", meta_json=b'{"pad": "' + b" " * (17 << 20) + b'"}')
    (inp / "nested_bundle").mkdir()
    (inp / "nested_bundle" / "manifest.json").write_text("{" + '"a": {' * 50_000 + "}" * 50_001)
    # memory: summed images, a sparse member, summed parts, a listed-twice part, a sparse gzip
    sog_of_big_images(inp / "g.sog", inp / "big_images.sog")
    unbundled_sog_with_sparse_member(inp / "g.sog", big / "unbundled")
    bundle_folder(big / "parts", [(f"particle_{i}.ply", 300_000) for i in range(10)])
    bundle_folder(inp / "twice", [("particle_0.ply", 40), ("particle_0.ply", 40)], copy_of=inp / "g.ply")
    sparse(big / "zeros.spz", GZIP_HEADER, 3 << 30)
    sparse(big / "tail.spz", (inp / "g.spz").read_bytes(), 3 << 30)  # a valid stream, then 3 GB the reader never needs
    # values past float32 and the world
    far = random_gaussians(40, 0, seed=5)
    far.means[1, 0] = 2.0e5  # 24-bit fixed point holds it (fewer fraction bits); the world does not
    write_spz(far, inp / "far.spz")
    compressed_ply_edited(inp / "g.compressed.ply", inp / "huge_bound.compressed.ply", chunk_values={"max_y": 3e38})
    sog_rewritten(inp / "g.sog", inp / "wide.sog", lambda m: m["scales"].update(codebook=[80.0] * 256))
    sog_rewritten(inp / "g.sog", inp / "overflow.sog", lambda m: m["means"].update(mins=[1e300] * 3))
    rec = np.frombuffer((inp / "g.splat").read_bytes(), dtype=np.uint8).copy()
    rec[32 * 7 + 4 : 32 * 7 + 8] = np.frombuffer(np.float32(-7e5).tobytes(), dtype=np.uint8)  # Gaussian 7's y
    (inp / "far.splat").write_bytes(rec.tobytes())
    # header fields of the wrong type
    sog_rewritten(inp / "sh.sog", inp / "bands_text.sog", lambda m: m["shN"].update(bands="3"))
    sog_rewritten(inp / "g.sog", inp / "count_true.sog", lambda m: m.update(count=True))
    sog_rewritten(inp / "g.sog", inp / "mins_bool.sog", lambda m: m["means"].update(mins=[True, 0, 0]))
    bundle_folder(inp / "float_count", [("particle_0.ply", 40)], copy_of=inp / "g.ply")
    edit_json(inp / "float_count" / "manifest.json", lambda m: m["parts"][0].update(gaussians=40.0))
    compressed_ply_edited(
        inp / "g.compressed.ply", inp / "dup.compressed.ply", lambda h: h.replace("float min_y\n", "float min_x\n")
    )
    sog_rewritten(inp / "g.sog", inp / "bad_image.sog", quats_webp=vp8l_header(8, 8, b"\xff" * 64))
    # the robot's scene keys: bases that are no rigid pose, a gripper nobody knows
    base = np.asarray(json.loads((ROB0 / "scene.json").read_text())["robot_base"], dtype=np.float64)
    scaled, shear, lastrow, far_base = base.copy(), base.copy(), base.copy(), base.copy()
    scaled[:3, :3] *= 2.0
    shear[0, 1] += 0.1
    lastrow[3] = [0.0, 0.0, 1.0, 1.0]
    far_base[0, 3] = 2.0e5
    for name, m in (("scaled", scaled), ("shear", shear), ("lastrow", lastrow), ("far", far_base)):
        shutil.copytree(ROB0, inp / "robot" / name / "s")
        edit_json(inp / "robot" / name / "s" / "scene.json", lambda d, m=m: d.update(robot_base=m.tolist()))
    shutil.copytree(ROB0, inp / "robot" / "gripper" / "s")
    edit_json(inp / "robot" / "gripper" / "s" / "scene.json", lambda d: d.update(gripper="robotiq200"))
    # an edit's scale below the bound of every positive number
    ops = {"version": 2, "operations": [{"pick": {"frame": 4, "pixel": [73, 70]}, "scale": 1e-30}]}  # object 1
    (inp / "tiny_scale.yaml").write_text(json.dumps(ops))
    return {"w": w, "in": inp, "big": big}


def _refusals(x: dict[str, Path]) -> dict[str, tuple[list[str], str]]:
    """name -> (arguments, a regex the one line must match)."""
    i, big = x["in"], x["big"]

    def export(src: Path | str, out: Path | str, *more: str) -> list[str]:
        return ["export", "--ply", str(src), "--out", str(out), *more]

    def render(src: Path | str) -> list[str]:
        return ["render", "--ply", str(src), "--width", "32", "--height", "24", "--out", str(i / "o.png")]

    def robot(name: str, command: str) -> list[str]:
        folder = i / "robot" / name
        if command == "render":
            return [
                "render",
                "--scene",
                str(folder / "s"),
                "--width",
                "32",
                "--height",
                "24",
                "--out",
                str(i / "o.png"),
            ]
        if command == "encode":
            return ["encode", "--data", str(folder), "--out", str(i / "enc"), "--no-progress"]
        return ["eval", "--data", str(folder)]

    rigid = r"is not a rigid transform \(rotation must be orthonormal with det \+1 and the last row 0 0 0 1"
    return {
        # the output guard, before any work
        "export over its own .compressed.ply": (
            export(i / "g.compressed.ply", i / "g.compressed.ply"),
            r"--out \S+g.compressed.ply: is --ply \S+g.compressed.ply, which this command reads",
        ),
        "export --by particle over the bundle holding its --ply": (
            export(i / "bundle" / "particle_0.ply", i / "bundle", "--by", "particle"),
            r"--out \S+bundle: holds --ply \S+particle_0.ply, which this command reads, and its contents are replaced",
        ),
        "export into a locked run": (
            export(i / "g.ply", i / "locked_run" / "g.splat"),
            rf"--out \S+g.splat: lies in the run folder \S+locked_run, in use by process {os.getpid()}",
        ),
        "export over a .ply in its --scene": (
            ["export", "--scene", str(i / "scene"), "--out", str(i / "scene" / "points.ply")],
            r"--out \S+points.ply: would replace a file inside --scene \S+scene, which this command reads",
        ),
        "export --by particle over a bundle holding the user's file": (
            export(i / "g.ply", i / "user_bundle", "--by", "particle"),
            r"user_bundle: holds notes.txt, which its manifest.json does not list: the bundle is not replaced",
        ),
        # JSON through the checked reader
        "a deeply nested meta.json in a .sog, render": (
            render(i / "nested.sog"),
            r"nested.sog: meta.json: not valid JSON \(nested too deeply\)",
        ),
        "a 17 MB meta.json in a .sog, export": (
            export(i / "padded.sog", i / "o.ply"),
            r"padded.sog: meta.json: more than the 16,777,216 bytes a meta.json may have",
        ),
        "a deeply nested bundle manifest, export": (
            export(i / "nested_bundle" / "manifest.json", i / "o.ply"),
            r"nested_bundle/manifest.json: not valid JSON \(nested too deeply\)",
        ),
        # one memory budget: sized from headers, summed, reserved before reading
        "five 4096^2 images in a .sog, render": (
            render(i / "big_images.sog"),
            r"big_images.sog: meta.json: count 40 and 5 images of 83,886,080 pixels: needs about .* more than the "
            "memory limit",
        ),
        "a 2 GB member beside an unbundled meta.json, export": (
            export(big / "unbundled" / "meta.json", i / "o.ply"),
            r"unbundled/meta.json: meta.json: count 40 and 5 images of .* pixels: needs about 2.0 GiB",
        ),
        "ten parts of 300,000 Gaussians, render": (
            render(big / "parts" / "manifest.json"),
            r"parts/manifest.json: 10 parts of 3,000,000 Gaussians: needs about .* more than the memory limit",
        ),
        "a part listed twice, export": (
            export(i / "twice" / "manifest.json", i / "o.ply"),
            r"twice/manifest.json: parts.1.file: particle_0.ply is listed already as parts.0.file",
        ),
        "a 3 GB sparse .spz after its gzip header, export": (
            export(big / "zeros.spz", i / "o.ply"),
            r"zeros.spz: corrupt gzip stream",
        ),
        # decoded values within float32 and the world, the input named
        "a .spz position 2e5 m away, export": (
            export(i / "far.spz", i / "o.ply"),
            r"far.spz: means: 2e\+05 m at Gaussian 1 is beyond the \+-100000 m a position may hold",
        ),
        "a compressed .ply chunk bound of 3e38, render": (
            render(i / "huge_bound.compressed.ply"),
            r"huge_bound.compressed.ply: means: \S+ m at Gaussian \d+ is beyond the \+-100000 m a position may hold",
        ),
        "a .sog scale codebook of exp(80) m, export": (
            export(i / "wide.sog", i / "o.spz"),
            r"wide.sog: scales: exp\(80\) m at Gaussian 0 is beyond the 100000 m a Gaussian's size may hold",
        ),
        "a .sog position range of 1e300, render": (
            render(i / "overflow.sog"),
            r"overflow.sog: means: non-finite value at Gaussian 0",
        ),
        "a .splat position of -7e5 m, export": (
            export(i / "far.splat", i / "o.sog"),
            r"far.splat: means: -7e\+05 m at Gaussian 7 is beyond the \+-100000 m",
        ),
        # header fields read typed
        "shN.bands as text in a .sog, export": (
            export(i / "bands_text.sog", i / "o.ply"),
            r"bands_text.sog: meta.json: 'shN.bands' must be a whole number in 1..3, got '3'",
        ),
        "count: true in a .sog, render": (
            render(i / "count_true.sog"),
            r"count_true.sog: meta.json: 'count' must be a whole number >= 0, got True",
        ),
        "a bool among means.mins in a .sog, export": (
            export(i / "mins_bool.sog", i / "o.ply"),
            r"mins_bool.sog: meta.json: 'means.mins': expected 3 finite numbers, got \[True, 0, 0\]",
        ),
        "a part's gaussians of 40.0, render": (
            render(i / "float_count" / "manifest.json"),
            r"float_count/manifest.json: 'parts.0.gaussians' must be a whole number >= 0, got 40.0",
        ),
        "a compressed .ply declaring min_x twice, export": (
            export(i / "dup.compressed.ply", i / "o.ply"),
            r"dup.compressed.ply: property 'min_x' is declared twice in element 'chunk'",
        ),
        "a .sog image that does not decode, render": (
            render(i / "bad_image.sog"),
            r"bad_image.sog: quats.webp: not a readable image \((?!.*BytesIO)",
        ),
        # the robot's base is a rigid pose within the world; its gripper is one the program knows
        "a robot base scaled x2, render": (
            robot("scaled", "render"),
            rf"scaled/s/scene.json: key 'robot_base' {rigid}",
        ),
        "a sheared robot base, encode": (robot("shear", "encode"), rf"shear/s/scene.json: key 'robot_base' {rigid}"),
        "a robot base whose last row is 0 0 1 1, eval": (
            robot("lastrow", "eval"),
            rf"lastrow/s/scene.json: key 'robot_base' {rigid}",
        ),
        "a robot base 2e5 m away, render": (
            robot("far", "render"),
            r"far/s/scene.json: key 'robot_base' is 2e\+05 m from the origin, beyond the 100000 m",
        ),
        "an unknown gripper, render": (
            robot("gripper", "render"),
            r"gripper/s/scene.json: key 'gripper' is 'robotiq200', not a gripper this program knows \(panda, ",
        ),
        # the bounds of every positive number
        "an edit's scale of 1e-30, render": (
            ["render", "--scene", str(i / "scene"), "--edits", str(i / "tiny_scale.yaml"), "--out", str(i / "o.png")],
            r"tiny_scale.yaml: operations\[0\].scale: expected a positive number in \[1e-18, 1e\+18\], got 1e-30",
        ),
    }


def _successes(x: dict[str, Path]) -> dict[str, list[str]]:
    """name -> arguments of a command that must exit 0 within the cap."""
    out = x["w"] / "out"
    return {
        "a valid .spz followed by 3 GB of zeros, export": ["export", "--ply", str(x["big"] / "tail.spz"), "--out"]
        + [str(out / "tail.ply")],
    }


@pytest.fixture(scope="module")
def results(world, tmp_path_factory):
    refusals, successes = _refusals(world), _successes(world)
    specs = [
        {"entry": PS, "argv": argv, "cap_mb": CAP_MB, "timeout": 180, "watch": [str(world["in"])]}
        for argv, _ in refusals.values()
    ] + [{"entry": PS, "argv": argv, "cap_mb": CAP_MB, "timeout": 180} for argv in successes.values()]
    io = tmp_path_factory.mktemp("runner")
    (io / "cases.json").write_text(json.dumps(specs))
    proc = subprocess.run(
        [sys.executable, str(HERE / "runner.py"), str(io / "cases.json"), str(io / "out.json")],
        capture_output=True,
        text=True,
        timeout=1800,
        cwd=io,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads((io / "out.json").read_text())
    names = [*refusals, *successes]
    if os.environ.get("HOSTILE_REPORT"):  # per case: exit code, seconds, peak RSS
        rows = [
            {"case": n, "code": r["code"], "seconds": round(r["seconds"], 3), "max_rss_mb": round(r["max_rss_mb"])}
            for n, r in zip(names, res, strict=True)
        ]
        Path(os.environ["HOSTILE_REPORT"]).write_text(json.dumps(rows, indent=1))
    return dict(zip(names, res, strict=True))


def _names(kind) -> list[str]:
    return list(kind({k: Path(k) for k in ("w", "in", "big")}).keys())


@pytest.mark.parametrize("name", _names(_refusals))
def test_case_is_one_line_exit_2_nothing_changed(results, world, name):
    res = results[name]
    lines = _lines(res["stderr"])
    assert not res["timed_out"] and res["code"] == 2, res["stderr"][-3000:]
    assert len(lines) == 1 and "Traceback" not in res["stderr"], res["stderr"][-3000:]
    assert re.search(_refusals(world)[name][1], lines[0]), lines[0]
    assert res["changed"] == [], res["changed"]


@pytest.mark.parametrize("name", _names(_successes))
def test_case_succeeds_within_the_cap(results, world, name):
    res = results[name]
    assert not res["timed_out"] and res["code"] == 0, res["stderr"][-3000:]
    assert res["stderr"].strip() == "", res["stderr"][-3000:]


def test_sigterm_mid_write_removes_the_temporary_file(world, tmp_path):
    """SIGTERM while ``export`` holds its finished temporary file (the rename is held back here, so the signal
    lands there every time): one line, exit 143, neither the temporary file nor the output is left."""
    code = (
        "import sys, time\n"
        "import particlesplat.core.atomic as atomic\n"
        "def held(tmp, path):\n"
        "    print('holding', tmp, flush=True)\n"
        "    time.sleep(120)\n"
        "atomic._put_in_place = held\n"
        "from particlesplat.cli.main import console_main\n"
        f"sys.argv = ['particlesplat', 'export', '--ply', {str(world['in'] / 'g.ply')!r}, '--out', "
        f"{str(tmp_path / 'x.sog')!r}]\n"
        "sys.exit(console_main())\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path
    )
    try:
        line = proc.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("holding"), line + proc.stderr.read()  # type: ignore[union-attr]
        tmp = Path(line.split()[1])
        assert tmp.is_file() and tmp.name.startswith(".x.sog.") and tmp.name.endswith(".tmp")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    assert err == "particlesplat export: interrupted (SIGTERM)\n", err[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_export_lets_a_bug_keep_its_traceback(world, tmp_path, monkeypatch, capsys):
    """``export`` prints one line for the project's user errors only: a bare ValueError (a bug) propagates."""
    import particlesplat.editing.open_scene as open_scene
    from particlesplat.cli.main import main
    from particlesplat.core.errors import UserError

    argv = ["export", "--ply", str(world["in"] / "g.ply"), "--out", str(tmp_path / "x.spz")]

    def bug(path):
        raise ValueError("a bug")

    monkeypatch.setattr(open_scene, "load_ply_checked", bug)
    with pytest.raises(ValueError, match="a bug"):
        main(argv)

    def user(path):
        raise UserError(f"{path}: a user's error")

    monkeypatch.setattr(open_scene, "load_ply_checked", user)
    assert main(argv) == 2
    assert capsys.readouterr().err == f"particlesplat export: {world['in'] / 'g.ply'}: a user's error\n"
    assert not (tmp_path / "x.spz").exists()


def test_reservations_add_up_within_a_job(monkeypatch):
    """Two reservations that each fit the limit do not fit together; leaving one gives its bytes back."""
    from particlesplat.core.limits import BudgetError, check_memory, reserve_memory, reserved_memory

    monkeypatch.setenv("PARTICLESPLAT_MEMORY_LIMIT", "100M")
    with reserve_memory(60 << 20, "a"):
        assert reserved_memory() == 60 << 20
        with pytest.raises(BudgetError, match=r"^b: needs about 60.0 MiB on top of the 60.0 MiB this job holds"):
            with reserve_memory(60 << 20, "b"):
                pass
        check_memory(40 << 20, "c")  # 100 MiB in all: at the limit, not past it
        assert reserved_memory() == 60 << 20
    assert reserved_memory() == 0
    with reserve_memory(60 << 20, "b"):
        pass


def test_image_sizes_from_headers_match_what_pillow_decodes():
    """The sizes read from the first 32 bytes are the decoded images' (WebP lossless, lossy with and without alpha,
    PNG); anything else is no header."""
    import io

    from PIL import Image

    from particlesplat.formats.image_headers import HEAD_BYTES, image_header_size

    for size in ((1, 1), (17, 5), (640, 3), (4096, 16383)):
        for mode, options in (("RGBA", {"lossless": True}), ("RGB", {"quality": 50}), ("RGBA", {"quality": 50})):
            buf = io.BytesIO()
            Image.new(mode, size, (10, 200, 30)).save(buf, format="WEBP", **options)
            data = buf.getvalue()
            assert image_header_size(data[:HEAD_BYTES]) == Image.open(io.BytesIO(data)).size == size, (size, options)
        buf = io.BytesIO()
        Image.new("RGB", size).save(buf, format="PNG")
        assert image_header_size(buf.getvalue()[:HEAD_BYTES]) == size
    assert image_header_size(webp_image(4096, 4096)[:HEAD_BYTES]) == (4096, 4096)
    for junk in (b"", b"RIFF", b"GIF89a" + bytes(40), bytes(64)):
        assert image_header_size(junk) is None


def test_header_fields_take_no_bool_for_a_number():
    from particlesplat.formats.header_fields import numbers, text_list, whole_number
    from particlesplat.formats.splat_arrays import SplatFileError

    meta = {"count": 3, "flag": True, "f": 2.0, "big": 10**400, "l": [1, 2.5], "b": [1, False], "n": ["a.webp"]}
    assert whole_number(meta, "m", "count") == 3
    for key in ("flag", "f", "big", "l"):
        with pytest.raises(SplatFileError, match=rf"^m: '{key}' must be a whole number"):
            whole_number(meta, "m", key, hi=10)
    assert numbers(meta, "m", "l").tolist() == [1.0, 2.5]
    with pytest.raises(SplatFileError, match=r"^m: 'b': expected 2 finite numbers, got \[1, False\]"):
        numbers(meta, "m", "b", length=2)
    with pytest.raises(SplatFileError, match=r"^m: 'n' must list 2 file name"):
        text_list(meta, "m", "n", min_length=2)
    with pytest.raises(SplatFileError, match=r"^m: missing 'x'"):
        whole_number(meta, "m", "x", "y")


@pytest.mark.parametrize(
    "edit, problem",
    [
        (lambda m: m.__setitem__((slice(0, 3), slice(0, 3)), m[:3, :3] * 1.01), "not a rigid transform"),
        (lambda m: m.__setitem__((slice(0, 3), 0), -m[:3, 0]), "det -1"),
        (lambda m: m.__setitem__(3, [0.0, 0.0, 0.0, 2.0]), "the last row 0 0 0 1"),
        (lambda m: m.__setitem__((1, 3), -1.5e5), "1.5e+05 m from the origin"),
        (lambda m: m.__setitem__((2, 2), np.nan), "non-finite"),
    ],
)
def test_a_pose_is_rigid_and_within_the_world(edit, problem):
    """A random rotation and translation pass; a stretch, a mirror, a last row, a far translation, a NaN do not."""
    from particlesplat.core.limits import rigid_problem

    q, r = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))  # a random orthonormal matrix
    m = np.eye(4)
    m[:3, :3] = q * np.linalg.det(q)  # a rotation: det +1
    m[:3, 3] = [3.0, -2.0, 0.5]
    assert rigid_problem(m) is None
    edit(m)
    assert problem in (rigid_problem(m) or ""), rigid_problem(m)


def test_sparse_ply_is_read_as_its_zeros(tmp_path):
    """The builder's sparse .ply is a valid file (so the budget, not a reader error, refuses ten of them)."""
    from particlesplat.formats.ply import read_ply

    fields = read_ply(sparse_ply(tmp_path / "z.ply", 5))
    assert fields.means.shape == (5, 3) and float(fields.scales.min()) == 1.0 and float(fields.opacities[0]) == 0.5
