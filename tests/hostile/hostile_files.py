"""Builders of hostile and broken files for the hostile-input suite: each is small on disk and
expands into something huge, or lies, or is torn, if a reader trusts it."""

from __future__ import annotations

import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import torch

# 9 levels of 9 aliases: 9**9 = 387 million leaves, 520 bytes on disk
ALIAS_BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [" + ", ".join([f"*{chr(97 + i)}"] * 9) + "]\n" for i in range(8)
)

_PLY_FIELDS = [
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


def alias_bomb_edits(path: Path) -> Path:
    """An edits file carrying an alias bomb (a printed or walked value would expand it)."""
    path.write_text("version: 1\nparticles:\n  0: {z_p: [0.1, 0.2]}\nscene:\n  " + ALIAS_BOMB.replace("\n", "\n  "))
    return path


def many_duplicates_edits(path: Path, count: int = 10_000) -> Path:
    """An edits file under the 1 MiB limit whose ``count`` duplicate operations would grow the scene without end
    (replayed naively, each pick decodes every copy made before it)."""
    op = "  - {pick: {frame: 0, pixel: [16, 16]}, duplicate: [0.0, 0.0, 0.0]}\n"
    path.write_text("version: 2\noperations:\n" + op * count)
    assert path.stat().st_size < 1 << 20
    return path


def alias_bomb_config(path: Path) -> Path:
    """A training config whose ``train.context_views`` is an alias bomb."""
    path.write_text("model: {}\n" + ALIAS_BOMB + "train:\n  context_views: *i\n")
    return path


def _ply(path: Path, declared: int, owners: list[int]) -> Path:
    rec = np.zeros(len(owners), dtype=np.dtype([(k, "<f4") for k in _PLY_FIELDS] + [("owner", "<i4")]))
    rec["rot_0"], rec["scale_0"], rec["scale_1"], rec["scale_2"] = 1.0, -3.0, -3.0, -3.0
    rec["owner"] = owners
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {declared}"]
    header += [f"property float {k}" for k in _PLY_FIELDS] + ["property int owner", "end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + rec.tobytes())
    return path


def huge_owner_ply(path: Path) -> Path:
    """A .ply of a few KB whose one owner is 2**31 - 1 (a viewer building range(max owner + 1) needs 24+ GB)."""
    return _ply(path, 64, [0] * 63 + [2**31 - 1])


def lying_count_ply(path: Path) -> Path:
    """A .ply whose header declares 10**9 vertices over a body of 4."""
    return _ply(path, 10**9, [0, 1, 2, -1])


def png_bomb(path: Path, width: int = 100000, height: int = 100000) -> Path:
    """A few-KB grey PNG declaring width x height pixels (10**10 by default)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(b"\0" * (width + 1) * 8))
        + chunk(b"IEND", b"")
    )
    return path


def bomb_scene(good_scene: Path, folder: Path) -> Path:
    """A copy of ``good_scene`` whose frame 1 colour image is a decompression bomb."""
    import json

    shutil.copytree(good_scene, folder)
    meta = json.loads((folder / "transforms.json").read_text())
    png_bomb(folder / meta["frames"][1]["file_path"])
    return folder


def nan_checkpoint(good: Path, path: Path) -> Path:
    """A copy of checkpoint ``good`` with one NaN weight (what a diverged run would have saved)."""
    ckpt = torch.load(good, weights_only=True)
    first = next(k for k, v in ckpt["state_dict"].items() if v.is_floating_point())
    ckpt["state_dict"][first].view(-1)[0] = float("nan")
    torch.save(ckpt, path)
    return path


def tear_log(path: Path, where: str) -> Path:
    """Tear a metrics.jsonl: its last line cut mid-record (``where="last"``, a disk that filled up) or a
    record before the last one cut (``"middle"``, a file edited by hand)."""
    lines = path.read_text().splitlines(keepends=True)
    if where == "last":
        path.write_text("".join(lines) + lines[-1][: len(lines[-1]) // 2])
    else:
        path.write_text(lines[0][: len(lines[0]) // 2] + "\n" + "".join(lines[1:]))
    return path


def scene_with(good_scene: Path, folder: Path, edit) -> Path:
    """A copy of ``good_scene`` whose transforms.json is changed by ``edit(meta, folder)``."""
    import json

    shutil.copytree(good_scene, folder)
    meta = json.loads((folder / "transforms.json").read_text())
    edit(meta, folder)
    (folder / "transforms.json").write_text(json.dumps(meta))
    return folder


def many_frames_one_image(good_scene: Path, folder: Path, frames: int = 200, side: int = 4096) -> Path:
    """A few-KB scene whose ``frames`` frames all name one ``side`` x ``side`` image (decoded: frames x 50 MB)."""

    def edit(meta, f):
        png_bomb(f / "big.png", side, side)
        frame = {**meta["frames"][0], "file_path": "big.png", "w": side, "h": side}
        frame.pop("depth_file_path", None)
        frame.pop("instance_mask_path", None)
        meta["frames"] = [dict(frame) for _ in range(frames)]

    return scene_with(good_scene, folder, edit)


def big_config_checkpoint(good: Path, path: Path, **model) -> Path:
    """A copy of checkpoint ``good`` (a few KB of weights) whose config, with a valid digest, builds a model of
    ``model`` (e.g. token_dim 2048 and 64 transformer layers: ~8.6 GB of weights)."""
    from particlesplat.model.config import flat_model_dict, nested_model_dict
    from particlesplat.model.io import config_digest

    ckpt = torch.load(good, weights_only=True)
    ckpt["config"] = nested_model_dict({**flat_model_dict(ckpt["config"], str(good)), **model})
    ckpt["config_sha256"] = config_digest(ckpt["config"])
    torch.save(ckpt, path)
    return path


def sparse_checkpoint(good: Path, path: Path) -> Path:
    """A copy of checkpoint ``good`` whose first weight is a sparse tensor (same values)."""
    ckpt = torch.load(good, weights_only=True)
    first = next(k for k, v in ckpt["state_dict"].items() if v.is_floating_point() and v.dim() == 2)
    ckpt["state_dict"][first] = ckpt["state_dict"][first].to_sparse()
    torch.save(ckpt, path)
    return path


def png_with_camera(path: Path, camera_text: str) -> Path:
    """A small PNG whose 'camera' text chunk is ``camera_text``."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_itxt("camera", camera_text)
    Image.new("RGB", (4, 4)).save(path, pnginfo=info)
    return path


def lock_run(run: Path, pid: int, host: str | None = None) -> Path:
    """Write ``run``'s lock file as process ``pid`` on ``host`` (default: this host) would."""
    import json
    import socket
    import time

    (run / ".lock").write_text(json.dumps({"pid": pid, "host": host or socket.gethostname(), "started": time.time()}))
    return run


def spz_gzip_bomb(path: Path, megabytes: int = 700) -> Path:
    """A 0.7 MB SPZ whose header declares 1,000 points but whose gzip stream inflates to ``megabytes`` MB."""
    head = struct.pack("<IIIBBBB", 0x5053474E, 3, 1000, 0, 12, 0, 0)
    z = zlib.compressobj(9, zlib.DEFLATED, 31)  # a gzip stream
    chunk = bytes(1 << 20)
    path.write_bytes(z.compress(head) + b"".join(z.compress(chunk) for _ in range(megabytes)) + z.flush())
    return path


def sog_claiming(path: Path, count: int = 10**9) -> Path:
    """A SOG zip of one meta.json declaring ``count`` Gaussians (a reader that sizes arrays by it first needs
    hundreds of GB)."""
    import json
    import zipfile

    meta = {
        "version": 2,
        "count": count,
        "means": {"mins": [0, 0, 0], "maxs": [1, 1, 1], "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": [0.0] * 256, "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": [0.0] * 256, "files": ["sh0.webp"]},
    }
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("meta.json", json.dumps(meta))
    return path


def checkpoint_with(good: Path, path: Path, weights=None, **keys) -> Path:
    """A copy of checkpoint ``good`` with top-level ``keys`` replaced (e.g. ``provenance``, ``train``) and every
    floating-point weight passed through ``weights`` (e.g. ``lambda v: v * 1e30``)."""
    ckpt = torch.load(good, weights_only=True)
    ckpt.update(keys)
    if weights is not None:
        ckpt["state_dict"] = {k: weights(v) if v.is_floating_point() else v for k, v in ckpt["state_dict"].items()}
    torch.save(ckpt, path)
    return path


def big_log(path: Path, megabytes: int) -> Path:
    """A metrics.jsonl of ``megabytes`` MB: training records of ~100 bytes, a validation record every 1,000 lines
    (what a long run with log_every 1 writes)."""
    import json

    block = "".join(
        json.dumps({"step": i, "loss": 917.1, "psnr": 14.48, "active": 7.0, "rec": 0.5}) + "\n" for i in range(999)
    )
    block += json.dumps({"step": 999, "val": {"psnr": 20.0, "fg_ari": 0.5}}) + "\n"
    data = block.encode()
    with open(path, "wb") as f:
        for _ in range(megabytes * (1 << 20) // len(data) + 1):
            f.write(data)
    return path


def edit_json(path: Path, edit) -> Path:
    """Apply ``edit(data)`` to the JSON file at ``path`` (in place)."""
    import json

    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    return path


def big_gaussians_ply(path: Path, count: int = 20_000, size: float = 0.5) -> Path:
    """A .ply of ``count`` Gaussians of ``size`` metres about the origin (a 1.4 MB file that covers every tile)."""
    from particlesplat.core.gaussians import Gaussians
    from particlesplat.formats.ply import write_ply

    g = torch.Generator().manual_seed(0)
    means = (torch.rand(count, 3, generator=g) - 0.5) * 2
    quats = torch.tensor([1.0, 0, 0, 0]).expand(count, 4).clone()
    owner = torch.full((count,), -1, dtype=torch.int64)
    write_ply(
        Gaussians(
            means,
            quats,
            torch.full((count, 3), size),
            torch.full((count,), 0.5),
            torch.rand(count, 1, 3, generator=g),
            owner,
        ),
        path,
    )
    return path


def lying_npz(path: Path, declared: tuple[int, ...] = (10**10, 4)) -> Path:
    """An .npz whose every member is a tiny float32 array but whose ``z_p`` header declares ``declared`` (149 GiB
    for the default); its meta is a valid JSON object."""
    import io
    import zipfile

    import numpy as np

    from particlesplat.analysis.particle_arrays import ARRAY_NAMES

    with zipfile.ZipFile(path, "w") as z:
        for name in ARRAY_NAMES:
            buf = io.BytesIO()
            np.save(buf, np.zeros((1, 1), np.float32))
            data = buf.getvalue()
            if name == "z_p":
                header = {"descr": "<f4", "fortran_order": False, "shape": declared}
                buf = io.BytesIO()
                np.lib.format.write_array_header_1_0(buf, header)
                data = buf.getvalue() + b"\0" * 16
            z.writestr(f"{name}.npy", data)
        buf = io.BytesIO()
        np.save(buf, np.array('{"format_version": 0}'))
        z.writestr("meta.npy", buf.getvalue())
    return path
