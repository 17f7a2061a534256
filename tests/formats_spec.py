"""Readers of the Gaussian file formats written from their published specs, one record at a time with ``struct``,
sharing nothing with ``particlesplat.formats``; and the demo scene the format tests write.

Each reader returns a dict of float64 arrays in the INRIA ``.ply``'s conventions: ``means`` (N, 3), ``quats``
(N, 4) wxyz (unit), ``log_scales`` (N, 3), ``opacities`` (N,) in [0, 1], ``dc`` (N, 3) the DC SH coefficient, and
``rest`` (N, K - 1, 3) the higher SH coefficients.

- ``.splat``: antimatter15/splat's ``main.js`` (32-byte records: 3 float32 position, 3 float32 scale, RGBA
  uint8, quaternion uint8 ``(q * 128 + 128)``);
- SPZ v3: nianticlabs/spz ``docs/SPZ.md`` (gzip; 16-byte header; positions int24 fixed point, alphas, colours
  ``dc * 0.15 * 255 + 127.5``, scales ``(log + 10) * 16``, smallest-three rotations, SH ``(c * 128 + 128)``);
- SPZ v4: the same arrays in nianticlabs/spz's ``README.md`` "File layout (version 4)" (a 32-byte plaintext
  header, extension records ``type, length, payload``, a table of contents of ``(compressed, inflated)`` uint64
  pairs, one ZSTD frame per non-empty array), read and written here (:func:`write_spz4_spec`);
- compressed ``.ply``: PlayCanvas's engine ``ply`` loader and splat-transform's writer documentation (chunk
  bounds, 11-10-11 / 2-10-10-10 / 8-8-8-8 packed words, SH bytes ``(c / 8 + 0.5) * 256``);
- SOG v2: developer.playcanvas.com "The SOG Format" (meta.json, WebP images, codebooks, ``sign(x) log(|x| + 1)``
  positions on 16 bits, quaternion tag 252 + index).
"""

from __future__ import annotations

import functools
import gzip
import io
import json
import math
import struct
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

C0 = 0.28209479177387814  # the degree-0 SH basis constant, 1 / (2 sqrt(pi))


@functools.lru_cache(maxsize=1)
def demo_gaussians():
    """The first demo scene decoded by the shipped model (10,304 Gaussians), on the CPU."""
    import torch

    from particlesplat.editing.open_scene import demo_scenes, load_model_scene

    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, demo_scenes()[0], None)
    with torch.no_grad():
        return model.decode(enc.particles).detach().to("cpu")


def _out(means, quats, log_scales, opacities, dc, rest) -> dict[str, np.ndarray]:
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return {
        "means": np.asarray(means, dtype=np.float64).reshape(-1, 3),
        "quats": q,
        "log_scales": np.asarray(log_scales, dtype=np.float64).reshape(-1, 3),
        "opacities": np.asarray(opacities, dtype=np.float64),
        "dc": np.asarray(dc, dtype=np.float64).reshape(-1, 3),
        "rest": np.asarray(rest, dtype=np.float64),
    }


def read_splat_spec(path: Path) -> dict[str, np.ndarray]:
    data = Path(path).read_bytes()
    assert len(data) % 32 == 0
    means, quats, logs, ops, dcs = [], [], [], [], []
    for off in range(0, len(data), 32):
        x, y, z, sx, sy, sz = struct.unpack_from("<6f", data, off)
        r, g, b, a, q0, q1, q2, q3 = struct.unpack_from("<8B", data, off + 24)
        means.append((x, y, z))
        logs.append(tuple(math.log(max(s, 1e-30)) for s in (sx, sy, sz)))
        dcs.append(tuple((c / 255 - 0.5) / C0 for c in (r, g, b)))
        ops.append(a / 255)
        quats.append(tuple((v - 128) / 128 for v in (q0, q1, q2, q3)))
    n = len(means)
    return _out(means, quats, logs, ops, dcs, np.zeros((n, 0, 3)))


def read_spz_spec(path: Path) -> dict[str, np.ndarray]:
    raw = gzip.decompress(Path(path).read_bytes())
    magic, version, n, degree, frac, flags, reserved = struct.unpack_from("<IIIBBBB", raw, 0)
    assert magic == 0x5053474E and version == 3 and reserved == 0, (hex(magic), version, reserved)
    dim = {0: 0, 1: 3, 2: 8, 3: 15}[degree]
    off = 16
    means = []
    for _ in range(n):
        p = []
        for _axis in range(3):
            b = raw[off : off + 3]
            off += 3
            v = b[0] | (b[1] << 8) | (b[2] << 16)
            if v & 0x800000:
                v -= 1 << 24
            p.append(v / (1 << frac))
        means.append(p)
    ops = [raw[off + i] / 255 for i in range(n)]
    off += n
    dcs = [[(raw[off + 3 * i + c] / 255 - 0.5) / 0.15 for c in range(3)] for i in range(n)]
    off += 3 * n
    logs = [[raw[off + 3 * i + c] / 16 - 10 for c in range(3)] for i in range(n)]
    off += 3 * n
    quats = []
    for i in range(n):
        (word,) = struct.unpack_from("<I", raw, off + 4 * i)
        largest = word >> 30
        xyzw = [0.0] * 4
        for j in (3, 2, 1, 0):  # the last stored component sits in the lowest bits
            if j == largest:
                continue
            mag, neg = word & 0x1FF, (word >> 9) & 1
            word >>= 10
            xyzw[j] = (-1 if neg else 1) * math.sqrt(0.5) * mag / 511
        xyzw[largest] = math.sqrt(max(0.0, 1 - sum(v * v for v in xyzw)))
        quats.append([xyzw[3], xyzw[0], xyzw[1], xyzw[2]])
    off += 4 * n
    rest = np.zeros((n, dim, 3))
    for i in range(n):
        for k in range(dim):
            for c in range(3):
                rest[i, k, c] = (raw[off] - 128) / 128
                off += 1
    assert off == len(raw)
    return _out(means, quats, logs, ops, dcs, rest)


SPZ4_SH_DIM = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}  # higher SH coefficients a channel, by degree


def write_spz4_spec(
    path: Path, g: dict[str, np.ndarray], frac: int = 12, extensions: tuple[tuple[int, bytes], ...] = ()
) -> None:
    """Write the Gaussians ``g`` (the spec readers' dict; ``rest`` (N, 0/3/8/15/24, 3)) as an SPZ version 4 file,
    one value at a time from the spec: positions int24 with ``frac`` fraction bits, alpha ``opacity * 255``,
    colour ``dc * 0.15 * 255 + 127.5``, scale ``(log + 10) * 16``, rotation the smallest three of (x, y, z, w) on
    10 bits each below the largest's index, SH ``c * 128 + 128`` on 8 bits; ``extensions``: (type, payload)
    records after the header."""
    import zstandard

    n, dim = len(g["means"]), g["rest"].shape[1]
    degree = {v: k for k, v in SPZ4_SH_DIM.items()}[dim]
    byte = lambda v: max(0, min(255, int(round(v))))  # noqa: E731
    pos, alpha, colour, scale, rot, sh = bytearray(), bytearray(), bytearray(), bytearray(), bytearray(), bytearray()
    for i in range(n):
        for v in g["means"][i]:
            pos += struct.pack("<i", int(round(v * (1 << frac))))[:3]
        alpha.append(byte(g["opacities"][i] * 255))
        colour += bytes(byte(c * 0.15 * 255 + 127.5) for c in g["dc"][i])
        scale += bytes(byte((v + 10) * 16) for v in g["log_scales"][i])
        w, x, y, z = g["quats"][i] / np.linalg.norm(g["quats"][i])
        xyzw = [x, y, z, w]
        largest = max(range(4), key=lambda j: abs(xyzw[j]))
        if xyzw[largest] < 0:
            xyzw = [-v for v in xyzw]
        word = largest
        for j in range(4):
            if j != largest:
                mag = min(511, int(round(abs(xyzw[j]) / math.sqrt(0.5) * 511)))
                word = (word << 10) | ((1 << 9) * (xyzw[j] < 0)) | mag
        rot += struct.pack("<I", word)
        for k in range(dim):
            sh += bytes(byte(c * 128 + 128) for c in g["rest"][i, k])
    streams = [bytes(b) for b in (pos, alpha, colour, scale, rot, sh) if b]
    packed = [zstandard.ZstdCompressor(level=3).compress(b) for b in streams]
    ext = b"".join(struct.pack("<II", kind, len(payload)) + payload for kind, payload in extensions)
    flags = 0x2 if extensions else 0
    toc = 32 + len(ext)
    head = struct.pack("<IIIBBBBI", 0x5053474E, 4, n, degree, frac, flags, len(streams), toc) + bytes(12)
    table = b"".join(struct.pack("<QQ", len(c), len(u)) for c, u in zip(packed, streams, strict=True))
    Path(path).write_bytes(head + ext + table + b"".join(packed))


def read_spz4_spec(path: Path) -> dict[str, np.ndarray]:
    """An SPZ version 4 file read from the spec (all SH degrees, 0..4), one record at a time."""
    import zstandard

    data = Path(path).read_bytes()
    magic, version, n, degree, frac, _flags, count, toc = struct.unpack_from("<IIIBBBBI", data, 0)
    assert magic == 0x5053474E and version == 4 and data[20:32] == bytes(12)
    dim = SPZ4_SH_DIM[degree]
    off, streams = toc + 16 * count, []
    for i in range(count):
        csize, usize = struct.unpack_from("<QQ", data, toc + 16 * i)
        streams.append(zstandard.ZstdDecompressor().decompress(data[off : off + csize], max_output_size=usize))
        assert len(streams[-1]) == usize
        off += csize
    assert off == len(data)
    pos, alpha, colour, scale, rot = streams[:5]
    sh = streams[5] if dim else b""
    means = []
    for i in range(3 * n):
        v = pos[3 * i] | (pos[3 * i + 1] << 8) | (pos[3 * i + 2] << 16)
        means.append((v - (1 << 24) if v & 0x800000 else v) / (1 << frac))
    quats = []
    for i in range(n):
        (word,) = struct.unpack_from("<I", rot, 4 * i)
        largest, xyzw = word >> 30, [0.0] * 4
        for j in (3, 2, 1, 0):  # the last stored component sits in the lowest bits
            if j != largest:
                xyzw[j] = (-1 if word & 0x200 else 1) * math.sqrt(0.5) * (word & 0x1FF) / 511
                word >>= 10
        xyzw[largest] = math.sqrt(max(0.0, 1 - sum(v * v for v in xyzw)))
        quats.append([xyzw[3], xyzw[0], xyzw[1], xyzw[2]])
    rest = np.array([(b - 128) / 128 for b in sh], dtype=np.float64).reshape(n, dim, 3)
    return _out(
        means,
        quats,
        [b / 16 - 10 for b in scale],
        [b / 255 for b in alpha],
        [(b / 255 - 0.5) / 0.15 for b in colour],
        rest,
    )


def _ply_elements(data: bytes) -> tuple[list[tuple[str, int, list[tuple[str, str]]]], int]:
    end = data.index(b"end_header\n") + len(b"end_header\n")
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for line in data[:end].decode("ascii").splitlines():
        w = line.split()
        if w[0] == "element":
            elements.append((w[1], int(w[2]), []))
        elif w[0] == "property":
            elements[-1][2].append((w[2], w[1]))
    return elements, end


def read_compressed_ply_spec(path: Path) -> dict[str, np.ndarray]:
    data = Path(path).read_bytes()
    elements, off = _ply_elements(data)
    codes = {"float": "f", "uint": "I", "uchar": "B"}
    rows: dict[str, list[dict[str, float]]] = {}
    for name, count, props in elements:
        fmt = "<" + "".join(codes[t] for _, t in props)
        size = struct.calcsize(fmt)
        rows[name] = [
            dict(zip([p for p, _ in props], struct.unpack_from(fmt, data, off + i * size), strict=True))
            for i in range(count)
        ]
        off += count * size
    chunks, verts = rows["chunk"], rows["vertex"]

    def unorm(v: int, bits: int) -> float:
        return (v & ((1 << bits) - 1)) / ((1 << bits) - 1)

    def lerp(a: float, b: float, t: float) -> float:
        return a + (b - a) * t

    means, quats, logs, ops, dcs = [], [], [], [], []
    for i, v in enumerate(verts):
        ch = chunks[i // 256]
        pp, ps, pc, pr = v["packed_position"], v["packed_scale"], v["packed_color"], v["packed_rotation"]
        means.append(
            [
                lerp(ch[f"min_{a}"], ch[f"max_{a}"], unorm(pp >> s, b))
                for a, s, b in (("x", 21, 11), ("y", 11, 10), ("z", 0, 11))
            ]
        )
        logs.append(
            [
                lerp(ch[f"min_scale_{a}"], ch[f"max_scale_{a}"], unorm(ps >> s, b))
                for a, s, b in (("x", 21, 11), ("y", 11, 10), ("z", 0, 11))
            ]
        )
        dcs.append(
            [
                (lerp(ch[f"min_{c}"], ch[f"max_{c}"], unorm(pc >> s, 8)) - 0.5) / C0
                for c, s in (("r", 24), ("g", 16), ("b", 8))
            ]
        )
        ops.append(unorm(pc, 8))
        largest = pr >> 30
        vals = [(unorm(pr >> s, 10) - 0.5) * math.sqrt(2) for s in (20, 10, 0)]
        q = [0.0] * 4
        for j, val in zip([j for j in range(4) if j != largest], vals, strict=True):
            q[j] = val
        q[largest] = math.sqrt(max(0.0, 1 - sum(x * x for x in vals)))
        quats.append(q)
    n = len(verts)
    if "sh" in rows:
        m = len(rows["sh"][0]) if n else 0
        rest = np.array([[((r[f"f_rest_{j}"] + 0.5) / 256 - 0.5) * 8 for j in range(m)] for r in rows["sh"]])
        rest = rest.reshape(n, 3, m // 3).transpose(0, 2, 1)
    else:
        rest = np.zeros((n, 0, 3))
    return _out(means, quats, logs, ops, dcs, rest)


def read_sog_spec(path: Path) -> dict[str, np.ndarray]:
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("meta.json"))

        def image(name: str) -> list[tuple[int, int, int, int]]:
            im = Image.open(io.BytesIO(z.read(name))).convert("RGBA")
            return [tuple(px) for px in np.asarray(im).reshape(-1, 4).tolist()]  # row-major pixels

        assert meta["version"] == 2
        n = meta["count"]
        lo, hi = image(meta["means"]["files"][0]), image(meta["means"]["files"][1])
        qs, sc, s0 = image(meta["quats"]["files"][0]), image(meta["scales"]["files"][0]), image(meta["sh0"]["files"][0])
    mins, maxs = meta["means"]["mins"], meta["means"]["maxs"]
    sbook, cbook = meta["scales"]["codebook"], meta["sh0"]["codebook"]
    means, quats, logs, ops, dcs = [], [], [], [], []
    for i in range(n):
        p = []
        for a in range(3):
            t = (lo[i][a] + (hi[i][a] << 8)) / 65535
            v = mins[a] + (maxs[a] - mins[a]) * t
            p.append(math.copysign(math.exp(abs(v)) - 1, v))
        means.append(p)
        largest = qs[i][3] - 252
        vals = [(qs[i][c] / 255 * 2 - 1) / math.sqrt(2) for c in range(3)]
        q = [0.0] * 4
        for j, val in zip([j for j in range(4) if j != largest], vals, strict=True):
            q[j] = val
        q[largest] = math.sqrt(max(0.0, 1 - sum(x * x for x in vals)))
        quats.append(q)
        logs.append([sbook[sc[i][c]] for c in range(3)])
        dcs.append([cbook[s0[i][c]] for c in range(3)])
        ops.append(s0[i][3] / 255)
    return _out(means, quats, logs, ops, dcs, np.zeros((n, 0, 3)))


def rotation_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) |<a, b>| of unit quaternions: 1 for the same rotation (q and -q alike)."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.abs((a * b).sum(1))


def render_psnr(g, ref) -> float:
    """PSNR (dB) of a 320x240 render of Gaussians ``g`` against one of ``ref``, from ``ref``'s default view (the
    view ``particlesplat render --ply`` takes) on the default background."""
    import torch

    from particlesplat.analysis.metrics import psnr
    from particlesplat.core.viewpoints import default_view, scene_background
    from particlesplat.rendering.api import render

    camera = default_view(None, ref).camera(320, 240)
    with torch.no_grad():
        want = render(ref, camera, background=scene_background(None)).rgb.clamp(0, 1)
        got = render(g, camera, background=scene_background(None)).rgb.clamp(0, 1)
    return psnr(got, want)


def original(g) -> dict[str, np.ndarray]:
    """The Gaussians ``g`` as the spec readers return them (float64, unit quaternions, log scales, dc, rest)."""
    q = g.quats.double().numpy()
    return {
        "means": g.means.double().numpy(),
        "quats": q / np.linalg.norm(q, axis=1, keepdims=True),
        "log_scales": np.log(np.maximum(g.scales.double().numpy(), 1e-30)),
        "opacities": g.opacities.double().numpy(),
        "dc": g.sh[:, 0, :].double().numpy(),
        "rest": g.sh[:, 1:, :].double().numpy(),
    }


def assert_same_as_ours(ours, spec: dict[str, np.ndarray]) -> None:
    """Our reader's Gaussians (float32) equal the spec reader's to float32 rounding."""
    np.testing.assert_allclose(ours.means.double().numpy(), spec["means"], rtol=1e-6, atol=1e-6)
    assert rotation_dot(ours.quats.double().numpy(), spec["quats"]).min() > 1 - 1e-6
    np.testing.assert_allclose(np.log(ours.scales.double().numpy()), spec["log_scales"], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ours.opacities.double().numpy(), spec["opacities"], atol=1e-6)
    np.testing.assert_allclose(ours.sh[:, 0, :].double().numpy(), spec["dc"], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ours.sh[:, 1:, :].double().numpy(), spec["rest"], rtol=1e-5, atol=1e-5)


def random_gaussians(n: int, degree: int, seed: int):
    """``n`` Gaussians with SH ``degree``: positions in a 4 m cube, log scales in [-6, -1], opacities over [0, 1]
    (with exact 0 and 1), SH coefficients in [-1.5, 1.5] (DC) and [-0.5, 0.5] (higher), owners -1..3."""
    import torch

    from particlesplat.core.gaussians import Gaussians

    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    u = lambda *s: torch.rand(*s, generator=gen)  # noqa: E731
    opac = u(n)
    opac[:2] = torch.tensor([0.0, 1.0])
    sh = torch.cat([u(n, 1, 3) * 3 - 1.5, u(n, k - 1, 3) - 0.5], dim=1)
    return Gaussians(
        means=u(n, 3) * 4 - 2,
        quats=torch.randn(n, 4, generator=gen),
        scales=torch.exp(u(n, 3) * 5 - 6),
        opacities=opac,
        sh=sh,
        owner=torch.randint(-1, 4, (n,), generator=gen),
    )
