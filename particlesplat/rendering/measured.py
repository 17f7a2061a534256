"""``rasterizer: auto`` on the CPU: the rasterizer chosen by measurement, once per machine.

The fused kernels and their torch twin trade places between CPUs: on an AMD EPYC the fused training step was 1.3x
faster, on an Intel Xeon with AVX-512 its backward cost 2.2x torch's and the step was 0.67x. So the first time
``auto`` resolves on a machine, :func:`measured_choice` times both on a short fixed workload (:func:`timing_scene`,
rendered as a training step renders: several views in one pass, with the particles' weight column), forward alone
and forward + backward, and keeps the faster of each:

- renders without gradients (eval, ``render``, encode, the viewer's picking) take the faster forward;
- renders that carry gradients (training, fitting) take the faster forward + backward.

The choice is cached in ``$XDG_CACHE_HOME/particlesplat/rasterizer.json`` under a fingerprint of what decides it
(the CPU's model, its core count, torch's and numba's versions, this package's version and a digest of its
rasterizers' source; the threads it was measured at are recorded beside it); a new
fingerprint measures again. Measuring takes a few seconds and prints one line on stderr naming the choice, the
times and the cache file.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

from particlesplat.core.errors import UserError
from particlesplat.core.machine import cpu_model

if TYPE_CHECKING:
    from particlesplat.core.camera import Camera
    from particlesplat.core.gaussians import Gaussians

CACHE_NAME = "rasterizer.json"
CANDIDATES = ("fused", "torch")
# the fixed workload: Gaussians, views of SIZE x SIZE px, timed repeats a direction (median)
TIMING_GAUSSIANS = 4_000
TIMING_VIEWS = 2
TIMING_SIZE = 128
TIMING_REPEATS = 3
MAX_CACHE_ENTRIES = 32  # fingerprints kept (a shared home folder seen from several machines)

_chosen: dict[str, dict[str, str]] = {}  # fingerprint key -> {"forward": ..., "training": ...}, this process
_renderer: list[Callable[..., list]] = []  # render_batch, registered by rendering.api (which imports this module)


def set_workload_renderer(render_batch: Callable[..., list]) -> None:
    """Register the batch renderer the timing workload draws with (:func:`particlesplat.rendering.api.render_batch`,
    registered as that module loads: the renderer calls this module to choose, so this one cannot import it)."""
    _renderer[:] = [render_batch]


def _workload_renderer() -> Callable[..., list]:
    if not _renderer:
        raise RuntimeError("the rasterizer measurement runs once particlesplat.rendering.api is loaded")
    return _renderer[0]


def timing_scene(n: int, size: int, seed: int = 0) -> tuple[Gaussians, Camera]:
    """N random Gaussians (SH degree 1) filling a 2 x 2 x 1 m box seen from 3 m; a few px each at 128 px; owners
    -1..7 (a background and 8 particles). Returns the Gaussians and a size x size camera."""
    import torch

    from particlesplat.core.camera import Camera
    from particlesplat.core.gaussians import Gaussians

    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen) - 0.5) * torch.tensor([2.0, 2.0, 1.0])
    quats = torch.randn(n, 4, generator=gen)
    scales = torch.exp(torch.randn(n, 3, generator=gen) * 0.5) * 0.012
    opacities = torch.rand(n, generator=gen) * 0.9 + 0.05
    sh = torch.randn(n, 4, 3, generator=gen) * 0.3
    owner = torch.randint(-1, 8, (n,), generator=gen)
    cam = Camera.orbit((0.0, 0.0, 0.0), 20.0, 30.0, 3.0, width=size, height=size)
    return Gaussians(means, quats, scales, opacities, sh, owner), cam


KERNEL_SOURCES = (
    "fused.py",
    "fused_kernels.py",
    "fused_projection.py",
    "depth_order.py",
    "rasterize.py",
    "projection.py",
)
"""The modules of ``particlesplat.rendering`` whose code decides the two rasterizers' speed."""


@functools.cache
def kernels_digest() -> str:
    """The first 16 hex digits of the SHA-256 of :data:`KERNEL_SOURCES`: an install from a newer commit with the
    same package version still measures its own kernels again."""
    digest = hashlib.sha256()
    for name in KERNEL_SOURCES:
        digest.update((Path(__file__).parent / name).read_bytes())
    return digest.hexdigest()[:16]


def fingerprint() -> dict[str, object]:
    """What the choice depends on: the CPU's model, its cores, torch, numba, this package and its rasterizers' code
    (:func:`kernels_digest`). Torch's threads are not in it: the measured order of the two was the same at 1 and 2
    threads on both CPUs this project runs on."""
    import torch

    def version(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "none"

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "numba": version("numba"),
        "particlesplat": version("particlesplat"),
        "kernels": kernels_digest(),
    }


def _key(print_: dict[str, object]) -> str:
    return json.dumps(print_, sort_keys=True)


def time_rasterizers(
    n: int = TIMING_GAUSSIANS, size: int = TIMING_SIZE, views: int = TIMING_VIEWS, repeats: int = TIMING_REPEATS
) -> dict[str, dict[str, float]]:
    """Median ms of {"forward", "training"} (forward + backward) per rasterizer of :data:`CANDIDATES`, on ``views``
    orbit views of :func:`timing_scene` rendered in one pass with the foreground column, as the training loss renders.
    The rasterizers alternate within each repeat, so a load that comes and goes weighs on both alike."""
    import torch

    from particlesplat.core.camera import Camera
    from particlesplat.core.gaussians import Gaussians

    render_batch = _workload_renderer()
    with torch.inference_mode(False):
        g, _ = timing_scene(n, size)
    cams = [Camera.orbit((0.0, 0.0, 0.0), 20.0 + 40.0 * i, 30.0, 3.0, width=size, height=size) for i in range(views)]
    with torch.inference_mode(False), torch.enable_grad():
        means, quats, scales, opacities, sh = (
            t.detach().requires_grad_() for t in (g.means, g.quats, g.scales, g.opacities, g.sh)
        )
    trained = Gaussians(means, quats, scales, opacities, sh, g.owner)

    def forward(name: str) -> None:
        with torch.no_grad():
            render_batch([(g, c) for c in cams], foreground=True, rasterizer=name)

    def training(name: str) -> None:
        out = render_batch([(trained, c) for c in cams], foreground=True, rasterizer=name)
        loss = torch.zeros(())
        for r in out:
            assert r.foreground is not None  # asked for
            loss = loss + r.rgb.sum() + r.alpha.sum() + r.depth.sum() + r.foreground.sum()
        loss.backward()

    times: dict[str, dict[str, list[float]]] = {r: {"forward": [], "training": []} for r in CANDIDATES}
    # the first render of a no_grad or inference_mode block (eval) measures too: gradients on for the measurement
    with torch.inference_mode(False), torch.enable_grad():
        for name in CANDIDATES:  # warm-up: numba loads its cached kernels, torch its lazy state
            forward(name)
            training(name)
        for i in range(repeats):
            for name in CANDIDATES if i % 2 == 0 else CANDIDATES[::-1]:
                for kind, fn in (("forward", forward), ("training", training)):
                    t0 = time.perf_counter()
                    fn(name)
                    times[name][kind].append(1000.0 * (time.perf_counter() - t0))
    return {r: {k: statistics.median(v) for k, v in d.items()} for r, d in times.items()}


def choose(ms: dict[str, dict[str, float]]) -> dict[str, str]:
    """The faster rasterizer of each kind ({"forward", "training"}) in :func:`time_rasterizers`' times; a tie
    keeps torch (the reference)."""
    return {kind: min(reversed(CANDIDATES), key=lambda r: ms[r][kind]) for kind in ("forward", "training")}


def cache_path() -> Path:
    from particlesplat.core.userdirs import cache_dir

    return cache_dir() / CACHE_NAME


def _read_cache(path: Path) -> list[dict]:
    """The cache's entries; a missing, unreadable or malformed cache is none (it is measured again and rewritten)."""
    from particlesplat.core.jsonfile import read_json

    try:
        data = read_json(path, max_bytes=1 << 20)
    except (OSError, UserError):
        return []
    entries = data.get("entries") if isinstance(data, dict) else None
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def _cached(entries: list[dict], key: str) -> dict[str, str] | None:
    for entry in entries:
        chosen = entry.get("chosen")
        if (
            _key(entry.get("fingerprint", {})) == key
            and isinstance(chosen, dict)
            and all(chosen.get(k) in CANDIDATES for k in ("forward", "training"))
        ):
            return {k: chosen[k] for k in ("forward", "training")}
    return None


def _write_cache(path: Path, entries: list[dict]) -> None:
    """Write the cache atomically; a cache folder that cannot be written is no error (measured again next time)."""
    from particlesplat.core.atomic import atomic_write

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path, "w") as f:
            json.dump({"entries": entries[-MAX_CACHE_ENTRIES:]}, f, indent=1)
    except OSError:
        pass


def measured_choice(grad: bool) -> str:
    """'fused' or 'torch' for a CPU render (``grad``: it carries gradients), as measured on this machine: from this
    process's memo, else the cache file, else measured now (:func:`time_rasterizers`) and cached."""
    import torch

    print_ = fingerprint()
    key = _key(print_)
    if key not in _chosen:
        path = cache_path()
        entries = _read_cache(path)
        chosen = _cached(entries, key)
        if chosen is None:
            ms = time_rasterizers()
            chosen = choose(ms)
            entry = {
                "fingerprint": print_,
                "chosen": chosen,
                "ms": ms,
                "threads": torch.get_num_threads(),
                "measured": time.strftime("%Y-%m-%d %H:%M"),
            }
            _write_cache(path, [e for e in entries if _key(e.get("fingerprint", {})) != key] + [entry])
            print(describe(print_, chosen, ms, torch.get_num_threads(), path), file=sys.stderr)
        _chosen[key] = chosen
    return _chosen[key]["training" if grad else "forward"]


def describe(
    print_: dict[str, object], chosen: dict[str, str], ms: dict[str, dict[str, float]], threads: int, path: Path
) -> str:
    """The one line that says what ``auto`` chose on this machine and why."""
    times = "; ".join(
        f"{kind} fused {ms['fused'][kind]:.0f} ms, torch {ms['torch'][kind]:.0f} ms" for kind in ("forward", "training")
    )
    return (
        f"rasterizer auto: {chosen['forward']} for renders, {chosen['training']} for training, measured on "
        f"{print_['cpu']} at {threads} thread(s) ({times}); kept in {path}"
    )


def forget_choices() -> None:
    """Drop this process's memo (the cache file stays): the next ``auto`` reads the cache or measures again."""
    _chosen.clear()
