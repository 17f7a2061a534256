"""Numba kernels of the fused CPU rasterizer: binning, forward and analytic backward, one pass per tile.

They follow the rules of the torch twin (:mod:`particlesplat.rendering.rasterize`) exactly: 4×4-pixel tiles; a
Gaussian is listed in a tile iff its exponent reaches ln(1/255) − 1e-3 at one of the tile's pixel centres; lists
run front to back by depth (ties by row); at a pixel, α = min(0.99, exp(e)) with e = ln o − ½dᵀCd, α < 1/255 is
skipped, and the pixel stops before the Gaussian that would take its transmittance T to ≤ 1e-4.

Where the twin builds a padded (tile, pixel, slot) tensor per chunk and lets autograd hold per-pair tensors, these
kernels walk each tile's list once, all 16 pixels in step, stop as soon as every pixel of the tile is done, and
write per-pair gradients that the caller sums per Gaussian. Tiles run in parallel (``prange``); each pair belongs
to one tile, so no two threads write the same memory.

Inputs are numpy arrays (views of CPU tensors). Gaussian rows: means2d (M, 2) float64 pixels, conics (M, 3),
log_o (M,) ln opacity and features (M, C) in the working dtype (float32 or float64). The per-pixel arithmetic and
the sums run in float64 and are rounded to the working dtype once, on output, so the fused path is at least as
close to the float64 truth as the twin. Compiled on first use and cached on disk (``cache=True``: next to the
module, or in the user's cache directory where that is not writable; ``NUMBA_CACHE_DIR`` overrides).
"""

from __future__ import annotations

import math
import os
import threading
import types

import numba
import numpy as np
from numba import prange

from particlesplat.rendering.depth_order import depth_order

TILE = 4
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
HIT_MARGIN = 1e-3  # the binning test's margin below ln(1/255): the raster decides exactly
LOG_ALPHA_MIN = math.log(ALPHA_MIN)  # below this exponent α < 1/255: skipped before its exp() is paid

# Threads: numba's default layer, OpenMP where numba finds it, which shares torch's libgomp pool (on two cores,
# numba's own workqueue pool beside torch's spinning OpenMP threads made a 2-thread render 1.4-1.8x slower). A process
# forked after that pool started must not start OpenMP threads of its own (GNU OpenMP aborts it), so a forked child
# runs the serial builds.
_in_forked_child = False


def _forked() -> None:
    global _in_forked_child
    _in_forked_child = True


os.register_at_fork(after_in_child=_forked)
# parallel kernels are launched one at a time (callers from several Python threads take turns)
KERNEL_LOCK = threading.Lock()
PARALLEL_CHUNK = 32  # prange iterations (tiles, Gaussians, instances) a thread takes at a time

# no fastmath: the kernels must give the twin's results to float rounding (NaN and infinity rules included)
jit = numba.njit(nogil=True, cache=True, error_model="numpy")


class _Compiled:
    """A kernel compiled twice: serial for one thread (no thread pool wakes), ``prange``-parallel for more."""

    def __init__(self, py_func):
        # a renamed copy for the serial build: numba's on-disk cache is keyed by the function's qualified name,
        # and the two builds must not share (and overwrite) one cache index
        serial = types.FunctionType(py_func.__code__, py_func.__globals__, py_func.__name__ + "_serial")
        serial.__qualname__ = py_func.__qualname__ + "_serial"
        self.serial = jit(serial)
        self.parallel = numba.njit(nogil=True, cache=True, error_model="numpy", parallel=True)(py_func)
        self.__doc__ = py_func.__doc__

    def __call__(self, *args):
        if _in_forked_child or sync_threads() == 1:
            return self.serial(*args)
        # small chunks handed out as threads free up, not one equal share each: tiles' lists differ in length,
        # and a thread the machine's other work delays would otherwise hold the whole kernel up
        with KERNEL_LOCK, numba.parallel_chunksize(PARALLEL_CHUNK):
            return self.parallel(*args)


def sync_threads() -> int:
    """The threads a kernel runs on: as many as torch uses (the thread governor may lower that during training).

    Starting numba's OpenMP pool sets the shared OpenMP thread count to numba's maximum, which is torch's count
    too: torch's is put back, or a one-thread run would go on every core."""
    import torch

    wanted = torch.get_num_threads()
    n = max(1, min(wanted, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    if numba.get_num_threads() != n:
        numba.set_num_threads(n)
    if torch.get_num_threads() != wanted:
        torch.set_num_threads(wanted)
    return n


def parallel_kernel(py_func):
    """Decorator: the function as a :class:`_Compiled` kernel."""
    return _Compiled(py_func)


# pixel p (0..15, row-major) of a tile: its centre relative to the tile centre, pixels
PIXEL_X = np.array([(p % TILE) + 0.5 - TILE / 2 for p in range(TILE * TILE)])
PIXEL_Y = np.array([(p // TILE) + 0.5 - TILE / 2 for p in range(TILE * TILE)])


@jit
def _exponent(dx: float, dy: float, a: float, b: float, c: float, lo: float) -> float:
    """ln o − ½ dᵀCd at one pixel, d = (dx, dy) = pixel − mean: every test and composite computes it so."""
    return lo - 0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy)


@jit
def _exponents(mx: float, my: float, a: float, b: float, c: float, lo: float, e: np.ndarray) -> float:
    """e[p] = :func:`_exponent` at the 16 pixels (tile-centred mean mx, my), branch-free so that it vectorises;
    returns the largest."""
    best = -np.inf
    for p in range(TILE * TILE):
        e[p] = _exponent(PIXEL_X[p] - mx, PIXEL_Y[p] - my, a, b, c, lo)
        best = max(best, e[p])
    return best


@jit
def _candidate_boxes(means2d, radius, view, view_sizes, view_tiles_x, view_first):
    """Per Gaussian row: the first tile of its footprint box and the box's width and height in tiles (0 if none).

    means2d (M, 2) f64; radius (M, 2) half extents in pixels (< 0: no footprint); view (M,) int64;
    view_sizes (V, 2) int64 (width, height); view_tiles_x, view_first (V,) int64.
    """
    M = means2d.shape[0]
    corner = np.zeros(M, np.int64)
    nx = np.zeros(M, np.int64)
    ny = np.zeros(M, np.int64)
    for i in range(M):
        v = view[i]
        w, h = view_sizes[v, 0], view_sizes[v, 1]
        mx, my = means2d[i, 0], means2d[i, 1]
        rx, ry = float(radius[i, 0]), float(radius[i, 1])
        if not (rx >= 0.0) or not (math.isfinite(mx) and math.isfinite(my)):
            continue
        # pixel u is covered if its centre u + 0.5 lies within [m - r, m + r]
        lox = max(math.ceil(mx - rx - 0.5), 0.0)
        loy = max(math.ceil(my - ry - 0.5), 0.0)
        hix = min(math.floor(mx + rx - 0.5), w - 1.0)
        hiy = min(math.floor(my + ry - 0.5), h - 1.0)
        if hix < lox or hiy < loy:
            continue
        t0x, t0y = int(lox // TILE), int(loy // TILE)
        nx[i] = int(hix // TILE) - t0x + 1
        ny[i] = int(hiy // TILE) - t0y + 1
        corner[i] = view_first[v] + t0y * view_tiles_x[v] + t0x
    return corner, nx, ny


@jit
def _max_exponent(mx: float, my: float, a: float, b: float, c: float, lo: float) -> float:
    """The largest of :func:`_exponents`' 16 values, without storing them."""
    best = -np.inf
    for p in range(TILE * TILE):
        best = max(best, _exponent(PIXEL_X[p] - mx, PIXEL_Y[p] - my, a, b, c, lo))
    return best


@parallel_kernel
def _test_candidates(order, corner, nx, ny, start, view, view_tiles_x, means2d, conics, log_o, tile_origin, hit):
    """hit[start[k] + j] = the j-th candidate tile of the k-th Gaussian in depth order if it passes the exact
    test, else -1 (parallel over Gaussians: each writes only its own segment).

    The pixel centre nearest the mean is tried first (the same arithmetic as the 16-pixel test): nine candidates in
    ten pass there, and only the others pay for all 16 pixels."""
    thresh = math.log(ALPHA_MIN) - HIT_MARGIN
    edge = TILE / 2 - 0.5  # the outermost pixel centre's offset from the tile centre
    for k in prange(order.shape[0]):
        i = order[k]
        n_x = nx[i]
        if n_x == 0:
            continue
        a, b, c = conics[i, 0], conics[i, 1], conics[i, 2]
        lo = log_o[i]
        tx = view_tiles_x[view[i]]
        for j in range(n_x * ny[i]):
            row, col = j // n_x, j % n_x
            tile = corner[i] + row * tx + col
            mx = means2d[i, 0] - tile_origin[tile, 0]
            my = means2d[i, 1] - tile_origin[tile, 1]
            dx = min(max(math.floor(mx + TILE / 2) + 0.5 - TILE / 2, -edge), edge) - mx
            dy = min(max(math.floor(my + TILE / 2) + 0.5 - TILE / 2, -edge), edge) - my
            if _exponent(dx, dy, a, b, c, lo) >= thresh:
                hit[start[k] + j] = tile
            else:
                hit[start[k] + j] = tile if _max_exponent(mx, my, a, b, c, lo) >= thresh else -1


@jit
def scatter_add_rows(index, values, out):
    """out[index[s]] += values[s] for s = 0, 1, ... in turn: torch's ``index_add_`` along dim 0, the same sums in
    the same order (bit for bit), serial; 3-4x faster here on a training step's 1.3 M pairs (out: (N, C), values:
    (S, C) of one dtype, index: (S,) int64)."""
    for s in range(index.shape[0]):
        i = index[s]
        for c in range(values.shape[1]):
            out[i, c] += values[s, c]


@jit
def _sort_pairs(order, start, nx, ny, hit, num_tiles):
    """Counting sort of the passed candidates by tile; within a tile the depth order is kept.

    Returns gauss (P,) int64 row per pair, tile_start (T + 1,) int64 offsets of each tile's list.
    """
    count = np.zeros(num_tiles + 1, np.int64)
    for s in range(hit.shape[0]):
        if hit[s] >= 0:
            count[hit[s] + 1] += 1
    tile_start = np.cumsum(count)
    fill = tile_start[:-1].copy()
    gauss = np.empty(tile_start[-1], np.int64)
    for k in range(order.shape[0]):
        i = order[k]
        for j in range(nx[i] * ny[i]):
            t = hit[start[k] + j]
            if t >= 0:
                gauss[fill[t]] = i
                fill[t] += 1
    return gauss, tile_start


def bin_tiles(means2d, radius, view, view_sizes, view_tiles_x, view_first, depths, conics, log_o, tile_origin):
    """Tile lists of all views: gauss (P,) int64 rows grouped by tile, front to back; tile_start (T + 1,) int64.

    depths: (M,) camera z (front to back, ties by row; only rows with a footprint are sorted);
    tile_origin: (T, 2) float64 tile centres in pixels.
    """
    corner, nx, ny = _candidate_boxes(means2d, radius, view, view_sizes, view_tiles_x, view_first)
    rows = np.flatnonzero(nx)
    order = depth_order(depths[rows], rows)
    per = (nx * ny)[order]
    start = np.zeros(order.shape[0] + 1, np.int64)
    np.cumsum(per, out=start[1:])
    hit = np.empty(int(start[-1]), np.int64)
    _test_candidates(order, corner, nx, ny, start, view, view_tiles_x, means2d, conics, log_o, tile_origin, hit)
    return _sort_pairs(order, start, nx, ny, hit, tile_origin.shape[0])


@parallel_kernel
def rasterize_forward(tile_start, gauss, tile_origin, means2d, conics, log_o, features, out, last):
    """Composite each tile's list front to back.

    out: (T, 16, C + 1) zeros, filled with Σ w·feature per pixel and Σ w in the last column; last: (T, 16) int64
    filled with 1 + the list position of the last Gaussian a pixel weighed (0 if none): the backward's bound.
    """
    n_tiles = tile_start.shape[0] - 1
    C = features.shape[1]
    for t in prange(n_tiles):
        s0, s1 = tile_start[t], tile_start[t + 1]
        if s1 == s0:
            continue
        T = np.ones(TILE * TILE, np.float64)
        acc = np.zeros((TILE * TILE, C + 1), np.float64)
        done = np.zeros(TILE * TILE, np.bool_)
        e = np.empty(TILE * TILE, np.float64)
        n_done = 0
        for s in range(s0, s1):
            i = gauss[s]
            mx = means2d[i, 0] - tile_origin[t, 0]
            my = means2d[i, 1] - tile_origin[t, 1]
            if _exponents(mx, my, conics[i, 0], conics[i, 1], conics[i, 2], log_o[i], e) < LOG_ALPHA_MIN:
                continue
            for p in range(TILE * TILE):
                if e[p] < LOG_ALPHA_MIN or done[p]:
                    continue
                alpha = min(math.exp(e[p]), ALPHA_MAX)
                if alpha < ALPHA_MIN:
                    continue
                t_next = T[p] * (1 - alpha)
                if t_next <= T_MIN:
                    done[p] = True
                    n_done += 1
                    continue
                w = alpha * T[p]
                for ch in range(C):
                    acc[p, ch] += w * features[i, ch]
                acc[p, C] += w
                T[p] = t_next
                last[t, p] = s - s0 + 1
            if n_done == TILE * TILE:
                break
        for p in range(TILE * TILE):
            for ch in range(C + 1):
                out[t, p, ch] = acc[p, ch]


@parallel_kernel
def rasterize_backward(tile_start, gauss, tile_origin, means2d, conics, log_o, features, out, last, grad_out, d_pair):
    """Gradients per pair from the upstream gradient of :func:`rasterize_forward`'s output.

    grad_out: (T, 16, C + 1); d_pair: (P, 6 + C) zeros, filled per pair with the gradient of
    [mean x, mean y, conic a, b, c, ln o] and of the C features (summed over the tile's pixels).
    With v_i = grad · [feature_i, 1], w_i = α_i T_i and S_i = Σ_{k>i} v_k w_k (= grad · out − Σ_{k≤i} v_k w_k):
    ∂L/∂e_i = v_i w_i − S_i α_i / (1 − α_i), 0 where α_i is clamped at 0.99.
    """
    n_tiles = tile_start.shape[0] - 1
    C = features.shape[1]
    for t in prange(n_tiles):
        s0 = tile_start[t]
        bound = 0
        for p in range(TILE * TILE):
            bound = max(bound, last[t, p])
        if bound == 0:
            continue
        T = np.ones(TILE * TILE, np.float64)
        d_row = np.zeros(6 + C, np.float64)
        total = np.zeros(TILE * TILE, np.float64)  # Σ_k v_k w_k = grad · out
        for p in range(TILE * TILE):
            acc = 0.0
            for ch in range(C + 1):
                acc += float(grad_out[t, p, ch]) * float(out[t, p, ch])
            total[p] = acc
        prefix = np.zeros(TILE * TILE, np.float64)
        e = np.empty(TILE * TILE, np.float64)
        for s in range(s0, s0 + bound):
            i = gauss[s]
            mx = means2d[i, 0] - tile_origin[t, 0]
            my = means2d[i, 1] - tile_origin[t, 1]
            a, b, c = float(conics[i, 0]), float(conics[i, 1]), float(conics[i, 2])
            if _exponents(mx, my, a, b, c, log_o[i], e) < LOG_ALPHA_MIN:
                continue
            d_row[:] = 0.0
            for p in range(TILE * TILE):
                if e[p] < LOG_ALPHA_MIN or s - s0 >= last[t, p]:
                    continue
                dx, dy = PIXEL_X[p] - mx, PIXEL_Y[p] - my
                alpha = min(math.exp(e[p]), ALPHA_MAX)
                if alpha < ALPHA_MIN:
                    continue
                w = alpha * T[p]
                T[p] = T[p] * (1 - alpha)
                v = float(grad_out[t, p, C])
                for ch in range(C):
                    g = float(grad_out[t, p, ch])
                    v += g * features[i, ch]
                    d_row[6 + ch] += w * g
                vw = v * w
                prefix[p] += vw
                if alpha >= ALPHA_MAX:
                    continue  # α is clamped: flat in the exponent
                d_e = vw - (total[p] - prefix[p]) * alpha / (1.0 - alpha)
                d_row[0] += d_e * (a * dx + b * dy)
                d_row[1] += d_e * (b * dx + c * dy)
                d_row[2] += -0.5 * d_e * dx * dx
                d_row[3] += -d_e * dx * dy
                d_row[4] += -0.5 * d_e * dy * dy
                d_row[5] += d_e
            for k in range(6 + C):
                d_pair[s, k] = d_row[k]
