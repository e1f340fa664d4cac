"""``irregular``: soft irregular shadow mapping (Johnson et al. 2009), for sphere and rectangle lights.

Every eye sample is stored in a light-view perspective grid (:func:`build_sample_grid`), umbrae are
an exact point-in-triangle depth-complexity count at the stored samples (:func:`count_umbrae`),
penumbrae are one exact signed edge integral per (sample, silhouette edge) pair selected by
penumbra quads (:func:`select_silhouette_edges`, :func:`build_penumbra_quads`,
:func:`bin_penumbra_quads`, :func:`accumulate_penumbrae`), and V = 1 - (umbra + penumbra),
clamped (:func:`compose_visibility`, Eq. 4 with C = 0). Steps, bookkeeping, parameters,
deviations and measured limits: ``docs/methods/irregular.md``.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np

from .._jit import (
    calling_thread_only,
    compact_indices,
    kernel,
    next_item,
    row_stride,
    run_slots,
    run_threads,
    start_slots,
    work_counter,
)
from ..analytic import atan2_upper, rect_beyond_segment_area
from ..geometry.silhouette import build_adjacency, facing, facing_from_planes
from ..raster.kernels import view_coords
from ..raster.rasterizer import bin_offsets, prefetch
from ..raster.view import VP_B, VP_FORWARD, VP_L, VP_ORIGIN, VP_R, VP_RIGHT, VP_T, VP_UP, View, light_frame, light_view
from .base import Method, MethodOutput, Param, register
from .ground_truth import BOUND_SAFETY, embree_coord, hit_point_at

#: a connected occluder component with at most this fraction of boundary edges is a solid (only its
#: light-facing triangles are counted); otherwise a sheet (both sides counted)
SOLID_MAX_BOUNDARY = 0.01
#: relative slack on every conservative bound (quads, bins, wedge entry), so that a skipped sample
#: provably has a zero contribution in floating point too
_SLACK = 1e-6


# ---------------------------------------------------------------------------------------------
# (a) construction: the light-view perspective grid of eye samples
# ---------------------------------------------------------------------------------------------
@dataclass
class SampleGrid:
    """Eye samples sorted into a light-view 3D perspective grid.

    Cells are (row, column) of a ``gx x gy`` image-plane grid x ``slices`` depth slices (by distance
    to the light centre, geometric). Cells are numbered bin-major: ``((bin * B*B + local) * S + s)``
    with ``B`` cells per bin side, so a cell column's slices are contiguous and every screen bin
    owns one contiguous range. ``start[c]:start[c+1]`` are cell c's samples in the sorted arrays.
    """

    vp: np.ndarray  # light view params (window (l, r, b, t) at vp[VP_L:VP_T + 1])
    gx: int
    gy: int
    bins: int  # cells per bin side (B)
    nbx: int
    nby: int
    slices: int
    dlo: float  # slice 0 starts here (distance to the light centre)
    dhi: float
    sbound: np.ndarray  # slice_bounds(dlo, dhi, slices): where each slice starts (slice_of)
    start: np.ndarray  # (nbx*nby*B*B*S + 1,) int64
    ix: np.ndarray  # (n,) float64 image-plane x/z of the sorted samples
    iy: np.ndarray
    pos: np.ndarray  # (n,3) float64 offset sample positions, sorted
    dist: np.ndarray  # (n,) float64 distance to the light centre
    order: np.ndarray  # (n,) int64 index into the input samples
    bin_maxd: np.ndarray  # (nbx*nby,) float64 maximum receiver distance per bin (0 when empty)
    dmax: float
    col_box: np.ndarray  # (n_columns, 6) 3D box (min xyz, max xyz) of each cell column's samples
    nonempty_cells: int = 0  # cells holding samples (a statistic)
    max_cell: int = 0  # the most samples in one cell

    @property
    def n_bins(self) -> int:
        return self.nbx * self.nby

    @functools.cached_property
    def max_column(self) -> int:
        """The most samples in one cell column (the kernels' per-column scratch)."""
        return int(np.diff(self.start[:: self.slices]).max()) if len(self.order) else 0

    @functools.cached_property
    def max_bin(self) -> int:
        """The most samples in one screen bin (the kernels' per-bin scratch)."""
        return int(np.diff(self.start[:: self.bins * self.bins * self.slices]).max()) if len(self.order) else 0


def slice_bounds(dlo: float, dhi: float, slices: int) -> np.ndarray:
    """The table of :func:`slice_of`: sb[s] (1 <= s < slices) = dlo (dhi / dlo)^(s / slices), the
    distance where slice s starts (geometric slicing); sb[0] = -inf, and +inf up to a length of a
    power of two plus one (the binary search's steps)."""
    P = 1
    while slices > P:
        P *= 2
    sb = np.full(P + 1, np.inf)
    sb[0] = -np.inf
    sb[1:slices] = np.maximum.accumulate(dlo * np.exp(np.arange(1, slices) * (np.log(dhi / dlo) / slices)))
    return sb


@kernel(inline=True)
def slice_of(d, sb):
    """Depth slice of distance ``d``: the largest s with sb[s] <= d (``slice_bounds``), in
    [0, slices - 1]; non-decreasing in ``d`` by construction (what the umbra's and the wedge's first
    slices need to be conservative). A branch-free binary search: no logarithm per sample (one
    cost half of the samples' keys)."""
    s = 0
    step = (sb.shape[0] - 1) >> 1
    while step > 0:
        s += step & -np.int64(sb[s + step] <= d)  # a mask, not a select (LLVM made the select a branch)
        step >>= 1
    return s


@kernel(nogil=True, nrt=False, noalias=True)
def _sample_keys_slot(slot, pts, vp, gx, gy, rx, ry, slices, sb, near, count, key, sc, counter, nslot):
    """Per sample: its grid key (bin, cell in bin, slice; -1 behind the view). Its image position
    and distance are computed again where the sort gathers the sample (:func:`sample_projection`,
    the same bits): written here as a 48-byte record per sample and gathered, they cost more
    (frames 0.989-0.994 without them, 2026-12-05). ``rx[cx] + ry[cy]`` is cell (cx, cy)'s
    number, bin-major (:func:`cell_numbers`: tables instead of two integer divisions per sample).
    Run by ``run_slots``: each slot takes the next run of ``_KEY_RUN`` samples (``next_item``)
    until none is left (with fixed halves, one thread finished ~0.15 ms after the other on
    `bunny`), ``sc[slot]`` its scratch (:func:`_sample_keys_run`; ``count``: the slices by
    counting)."""
    n = pts.shape[0]
    l, r, b, t = vp[VP_L], vp[VP_R], vp[VP_B], vp[VP_T]
    while True:
        q = next_item(counter) * _KEY_RUN
        if q >= n:
            break
        _sample_keys_run(
            q, min(q + _KEY_RUN, n), pts, vp, l, r, b, t, gx, gy, rx, ry, slices, sb, near, count, key, sc[slot]
        )


#: samples per work item of :func:`_sample_keys_slot`
_KEY_RUN = 4096
#: :func:`_sample_keys_run` takes its run this many samples at a time (its scratch stays in L1)
_KEY_CHUNK = 512
#: slice tables (``slice_bounds``: a power of two plus one entries) of at most this many entries
#: are searched by counting in :func:`_sample_keys_run` (a compare per entry, vectorized over the
#: chunk); longer ones by ``slice_of`` per sample
_COUNT_SLICES_MAX = 33
#: rows of :func:`_sample_keys_run`'s scratch: cell column and row, distance, slice, in front, then the
#: samples' coordinates
_KEY_ROWS = 8


@kernel(inline=True)
def sample_projection(vp, px, py, pz):
    """A sample's (x, y, z) in the grid's view ``vp`` (before the division by z) and its distance
    to the light centre, from its position (px, py, pz): the same expressions wherever a sample's
    image position or distance is needed (its key, :func:`_sample_keys_run`; its sorted record,
    :func:`_sort_slot`)."""
    x, y, z = view_coords(vp, px, py, pz)
    dx, dy, dz = px - vp[VP_ORIGIN], py - vp[VP_ORIGIN + 1], pz - vp[VP_ORIGIN + 2]
    return x, y, z, np.sqrt(dx * dx + dy * dy + dz * dz)


@kernel(inline=True)
def _sample_keys_run(q0, q1, pts, vp, l, r, b, t, gx, gy, rx, ry, slices, sb, near, count, key, sc):
    """Samples q0 to q1 - 1 of :func:`_sample_keys_slot`, in three loops through the scratch ``sc``
    (``_KEY_ROWS`` rows): every sample's cell column and row (0 behind the view: a select, not a
    branch), distance and whether it is in front; then its slice; then its key. With ``count``
    (a table of at most ``_COUNT_SLICES_MAX`` entries without NaN) the slice is the number of
    entries sb[1:] <= d, a compare per entry for the whole run (``slice_of``'s largest s with
    sb[s] <= d: the same, the table being non-decreasing), else ``slice_of``. One loop per sample
    with the binary search's data-dependent branches and its scalar divisions ran ~10 ns a sample;
    these vectorize. The same keys."""
    # unsigned indices: no negative-index wrap-around code at every access (a prange's index is
    # unsigned too; with signed ones _compose_slot's scatter ran slower in a micro-benchmark)
    for c0 in range(q0, q1, _KEY_CHUNK):
        k0, m = np.uint64(c0), np.uint64(min(c0 + _KEY_CHUNK, q1) - c0)
        for i in range(m):  # the coordinates to rows first: read from (n, 3) the next loop ran scalar
            sc[5, i], sc[6, i], sc[7, i] = pts[k0 + i, 0], pts[k0 + i, 1], pts[k0 + i, 2]
        for i in range(m):
            x, y, z, d = sample_projection(vp, sc[5, i], sc[6, i], sc[7, i])
            ok = z > near
            xx = x / z
            yy = y / z
            fx = min(max(np.floor((xx - l) / (r - l) * gx), 0.0), gx - 1.0)
            fy = min(max(np.floor((t - yy) / (t - b) * gy), 0.0), gy - 1.0)
            sc[0, i] = fx if ok else 0.0  # (behind the view: any cell, the key is -1)
            sc[1, i] = fy if ok else 0.0
            sc[2, i] = d
            sc[3, i] = 0.0
            sc[4, i] = 1.0 if ok else 0.0
        if count:
            for e in range(1, sb.shape[0] - 1):
                se = sb[e]
                for i in range(m):
                    sc[3, i] += 1.0 if se <= sc[2, i] else 0.0
        else:
            for i in range(m):
                sc[3, i] = slice_of(sc[2, i], sb)
        for i in range(m):
            c = (rx[np.uint64(sc[0, i])] + ry[np.uint64(sc[1, i])]) * slices + np.int64(sc[3, i])
            key[k0 + i] = c if sc[4, i] != 0.0 else -1


@kernel
def counting_sort(key, n_keys):
    """Stable counting sort of non-negative keys (negative keys are dropped): (start (n_keys+1),
    order). O(n + n_keys)."""
    cnt = np.zeros(n_keys + 1, np.int64)
    for k in range(key.shape[0]):
        if key[k] >= 0:
            cnt[key[k] + 1] += 1
    for c in range(n_keys):
        cnt[c + 1] += cnt[c]
    order = np.empty(cnt[n_keys], np.int64)
    fill = cnt[:-1].copy()
    for k in range(key.shape[0]):
        c = key[k]
        if c >= 0:
            order[fill[c]] = k
            fill[c] += 1
    return cnt, order


#: sort_samples' gather prefetches the sample this many samples ahead (``prefetch``)
_GATHER_AHEAD = 16


@kernel(nogil=True, nrt=False)
def _sort_slot(w, phase, key, pts, vp, hist, tot, start, order, sx, sy, sp, sd, sc):
    """One slot of :func:`sort_samples` (``run_slots``; C = ``hist.shape[0]`` slots), one phase per
    launch: 0, slot w counts the keys of its chunk of the input into ``hist[w]``; 1, the samples of
    its range of keys, all chunks, into ``tot[w + 1]``; 2, from ``tot[w]`` on, each key's first
    place (``start``) and each chunk's next place for it, key-major and chunk-minor (``hist``); 3,
    its chunk's samples scattered to their places in input order (``order``); 4, its range of the
    sorted samples gathered (their positions, and their image positions and distances from them:
    :func:`sample_projection`)."""
    C = hist.shape[0]
    n = key.shape[0]
    nk = hist.shape[1]
    if phase == 0:
        for c in range(nk):
            hist[w, c] = 0
        v = 0
        for k in range(w * n // C, (w + 1) * n // C):
            c = key[k]
            if c >= 0:
                hist[w, np.uint64(c)] += 1  # unsigned: no wrap-around code
                v += 1
        tot[C + 1 + w] = v  # the chunk's samples in front of the view
    elif phase == 1:
        t = 0
        for c in range(w * nk // C, (w + 1) * nk // C):
            for q in range(C):
                t += hist[q, c]
        tot[w + 1] = t
    elif phase == 2:
        t = tot[w]
        for c in range(w * nk // C, (w + 1) * nk // C):
            start[c] = t
            for q in range(C):
                h = hist[q, c]
                hist[q, c] = t
                t += h
    elif phase == 3:
        for k in range(w * n // C, (w + 1) * n // C):
            c = key[k]
            if c >= 0:
                i = hist[w, np.uint64(c)]
                hist[w, np.uint64(c)] = i + 1
                order[np.uint64(i)] = k
    else:
        m = order.shape[0]
        j1 = (w + 1) * m // C
        z = np.uint64(0)
        g = sc[w]
        for c0 in range(w * m // C, j1, _KEY_CHUNK):  # in chunks through the scratch ``sc[w]``
            c1 = min(c0 + _KEY_CHUNK, j1)
            for j in range(c0, c1):
                if j + _GATHER_AHEAD < j1:  # the samples are read in cell order: a cache miss each
                    kn = np.uint64(order[j + _GATHER_AHEAD])
                    prefetch(pts, (kn, z))
                    prefetch(pts, (kn, np.uint64(2)))
                k = np.uint64(order[j])
                px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
                sp[j, 0], sp[j, 1], sp[j, 2] = px, py, pz
                i = np.uint64(j - c0)
                g[0, i], g[1, i], g[2, i] = px, py, pz
            # then their image positions and distances from the scratch's rows (the same bits as
            # sample_projection): this loop vectorizes (in the gather's loop, its divisions and
            # square root ran scalar)
            b = np.uint64(c0)
            for i in range(np.uint64(c1 - c0)):
                x, y, zz, d = sample_projection(vp, g[0, i], g[1, i], g[2, i])  # (zz > near: it has a key)
                sx[b + i] = x / zz
                sy[b + i] = y / zz
                sd[b + i] = d


#: grids with fewer keys (cells x slices) than this take phase 2 of :func:`sort_samples` (the
#: places) on the calling thread, in one pass instead of phases 1 and 2 on the threads: on
#: `bunny`'s 73,728 keys two launches took ~0.3 ms for ~0.1 ms of work
_SERIAL_PLACES = 1 << 20


def sort_samples(key, pts, vp, n_keys: int):
    """(start (n_keys + 1), order, sx, sy, sp, sd): :func:`counting_sort` of the grid keys (the same
    ``start`` and ``order``: stable, negative keys dropped) and the sorted samples ``pts`` gathered
    with their image positions (x/z, y/z) and distances in the grid's view ``vp`` (sx, sy, sd),
    by the threads together (``_sort_slot``, its five phases; phases 1 and 2 as one serial pass,
    the rasterizer's ``bin_offsets`` (keys for tiles, chunks the same), below ``_SERIAL_PLACES``
    keys): the serial sort's scatter was the
    longest serial step of the frame. The places are key-major, chunk-minor, so the order is the
    serial sort's whatever the number of threads."""
    C = max(1, min(numba.get_num_threads(), len(key)))
    hist = np.empty((C, n_keys), np.int32)  # (a count of samples fits)
    tot = np.zeros(2 * C + 1, np.int64)  # the key ranges' first places, then the chunks' samples
    start = np.empty(n_keys + 1, np.int64)
    e0, e1, e2 = np.empty(0, np.int64), np.empty(0), np.empty((0, 3))  # (the outputs, not yet made)
    sc = np.empty((C, 3, _KEY_CHUNK))  # phase 4's scratch
    serial = C == 1 or n_keys < _SERIAL_PLACES
    for phase in (0,) if serial else (0, 1):  # (one range: it starts at 0)
        run_slots(_sort_slot, C, phase, key, pts, vp, hist, tot, start, e0, e1, e1, e2, e1, sc)
    if serial:
        bin_offsets(hist, start)  # (start[n_keys]: the total)
        m = int(start[n_keys])
    else:
        np.cumsum(tot[: C + 1], out=tot[: C + 1])
        m = int(tot[C + 1 :].sum())
        start[n_keys] = m
    order = np.empty(m, np.int64)
    sx, sy, sd = np.empty(m), np.empty(m), np.empty(m)
    sp = np.empty((m, 3))
    for phase in (3, 4) if serial else (2, 3, 4):
        run_slots(_sort_slot, C, phase, key, pts, vp, hist, tot, start, order, sx, sy, sp, sd, sc)
    return start, order, sx, sy, sp, sd


#: columns per work item of :func:`_column_boxes_slot`
_COLUMN_RUN = 256


@kernel(inline=True)
def _column_box(c, start, sp, sd, S, box, dmax, occ):
    """Column c's row of ``box``, ``dmax`` and ``occ`` (:func:`_column_boxes_slot`)."""
    ne = 0
    mc = 0
    for s in range(S):
        k = start[c * S + s + 1] - start[c * S + s]
        ne += k > 0
        mc = max(mc, k)
    occ[c, 0] = ne
    occ[c, 1] = mc
    m = 0.0
    for j in range(start[c * S], start[c * S + S]):
        m = max(m, sd[j])
    dmax[c] = m
    # the running box in locals (not read and written back through ``box`` at every sample: LLVM
    # cannot keep those in registers when it cannot tell ``box`` from ``sp``)
    x0 = y0 = z0 = np.inf
    x1 = y1 = z1 = -np.inf
    for j in range(start[c * S], start[c * S + S]):
        x, y, z = sp[j, 0], sp[j, 1], sp[j, 2]
        x0, y0, z0 = min(x0, x), min(y0, y), min(z0, z)
        x1, y1, z1 = max(x1, x), max(y1, y), max(z1, z)
    box[c, 0], box[c, 1], box[c, 2] = x0, y0, z0
    box[c, 3], box[c, 4], box[c, 5] = x1, y1, z1


@kernel(nogil=True, nrt=False, noalias=True)
def _column_boxes_slot(slot, start, sp, sd, S, box, dmax, occ, counter, nslot):
    """Per cell column: 3D box of its samples, their maximum distance to the light centre, and
    (for the statistics) how many of its cells hold samples and the most samples in one of them,
    into ``box``, ``dmax``, ``occ``. Run by ``run_slots``: each slot takes the next run of
    ``_COLUMN_RUN`` columns (``next_item``) until none is left (the samples lie unevenly in the
    columns: with halves, one thread took twice the other's time on `bunny`)."""
    nc = box.shape[0]
    while True:
        q = next_item(counter) * _COLUMN_RUN
        if q >= nc:
            break
        for c in range(q, min(q + _COLUMN_RUN, nc)):
            _column_box(c, start, sp, sd, S, box, dmax, occ)


def _column_boxes(start, sp, sd, S):
    """:func:`_column_boxes_slot` over every cell column, one slot per thread: (box (nc, 6),
    dmax (nc,), occ (nc, 2) int64)."""
    nc = (start.shape[0] - 1) // S
    box = np.empty((nc, 6))
    dmax = np.zeros(nc)
    occ = np.zeros((nc, 2), np.int64)
    run_threads(_column_boxes_slot, start, sp, sd, S, box, dmax, occ, work_counter())
    return box, dmax, occ


@kernel
def receivers_box(col_box):
    """(lo (3,), hi (3,)): the box of every grid sample, from the cell columns' boxes (one serial
    pass over the columns; empty columns hold [inf, -inf] and drop out)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for c in range(col_box.shape[0]):
        for k in range(3):
            lo[k] = min(lo[k], col_box[c, k])
            hi[k] = max(hi[k], col_box[c, 3 + k])
    return lo, hi


# The samples' min/max passes (``_extent``, ``_window_of``) run one contiguous block of the samples
# per slot and fold the slots' rows in slot order afterwards (in Python: a handful of rows). min and
# max are exact, and a fold over contiguous blocks taken in order keeps the first of equal values
# (as Numba's and Python's ``min``/``max`` do over the whole sequence: -0.0 against 0.0), so the
# bits are the serial loop's whatever the number of slots.
@kernel(nogil=True, nrt=False, noalias=True)
def _extent_slot(slot, pts, c, part, nslot):
    """Row ``slot`` of ``part`` (nslot, 8): (lo xyz, smallest distance to c, hi xyz, largest
    distance to c) of one contiguous block of the samples. Run by ``run_slots`` (:func:`_extent`)."""
    n = pts.shape[0]
    lo0 = lo1 = lo2 = d0 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    d1 = 0.0
    k0, k1 = np.uint64(slot * n // nslot), np.uint64((slot + 1) * n // nslot)  # unsigned: see _sample_keys_slot
    for k in range(k0, k1):
        x, y, z = pts[k, 0], pts[k, 1], pts[k, 2]
        lo0, lo1, lo2 = min(lo0, x), min(lo1, y), min(lo2, z)
        hi0, hi1, hi2 = max(hi0, x), max(hi1, y), max(hi2, z)
        dx, dy, dz = x - c[0], y - c[1], z - c[2]
        d2 = dx * dx + dy * dy + dz * dz
        d0, d1 = min(d0, d2), max(d1, d2)
    # (the square root once per block: it is monotonic and correctly rounded, so the same bits)
    part[slot, 0], part[slot, 1], part[slot, 2], part[slot, 3] = lo0, lo1, lo2, np.sqrt(d0)
    part[slot, 4], part[slot, 5], part[slot, 6], part[slot, 7] = hi0, hi1, hi2, np.sqrt(d1)


def _extent(pts, c):
    """(lo (3,), hi (3,), d0, d1): the samples' bounding box and their smallest and largest distance
    to c, one block of the samples per slot (:func:`_extent_slot`), the slots' rows folded in order
    (:func:`fold_extent`)."""
    nslot = numba.get_num_threads()
    part = np.empty((nslot, 8))
    run_slots(_extent_slot, nslot, pts, c, part, nslot)
    return fold_extent(part, pts.shape[0])


@kernel
def _fold_extent(part, ext):
    """``ext`` (8,) := the rows of ``part`` (``_extent_slot``'s layout) folded in order."""
    for i in range(3):
        ext[i] = np.inf
        ext[4 + i] = -np.inf
    ext[3], ext[7] = np.inf, 0.0
    for q in range(part.shape[0]):
        for i in range(3):
            ext[i] = min(ext[i], part[q, i])
            ext[4 + i] = max(ext[4 + i], part[q, 4 + i])
        ext[3], ext[7] = min(ext[3], part[q, 3]), max(ext[7], part[q, 7])


def fold_extent(part, n: int):
    """(lo (3,), hi (3,), d0, d1) of n samples from the rows of ``part`` (nrows, 8: lo xyz, smallest
    distance, hi xyz, largest distance; of consecutive runs of the samples, in order), folded in
    order: the bits of one pass over the samples (see above); d0 = d1 = 1 without samples."""
    ext = np.empty(8)
    _fold_extent(part, ext)
    d0, d1 = (float(ext[3]), float(ext[7])) if n else (1.0, 1.0)
    return ext[0:3].copy(), ext[4:7].copy(), d0, d1


@kernel(nogil=True, nrt=False, noalias=True)
def _window_of_slot(slot, pts, o, r, u, f, near, part, nslot):
    """Row ``slot`` of ``part`` (nslot, 6): the image-plane window (x0, x1, y0, y1) and depth range
    (z0, z1) of the samples in front of the view (o; r, u, f) in one contiguous block of the
    samples. Run by ``run_slots`` (:func:`_window_of`)."""
    n = pts.shape[0]
    x0, x1, y0, y1, z0, z1 = np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf
    k0, k1 = np.uint64(slot * n // nslot), np.uint64((slot + 1) * n // nslot)  # unsigned: see _sample_keys_slot
    for k in range(k0, k1):
        dx, dy, dz = pts[k, 0] - o[0], pts[k, 1] - o[1], pts[k, 2] - o[2]
        z = dx * f[0] + dy * f[1] + dz * f[2]
        if z > near:
            x = (dx * r[0] + dy * r[1] + dz * r[2]) / z
            y = (dx * u[0] + dy * u[1] + dz * u[2]) / z
            x0, x1, y0, y1 = min(x0, x), max(x1, x), min(y0, y), max(y1, y)
            z0, z1 = min(z0, z), max(z1, z)
    part[slot, 0], part[slot, 1], part[slot, 2], part[slot, 3], part[slot, 4], part[slot, 5] = x0, x1, y0, y1, z0, z1


def _window_of(pts, o, r, u, f, near):
    """The image-plane window (x0, x1, y0, y1) and depth range (z0, z1) of the samples in front of
    the view (o; r, u, f), one block of the samples per slot (:func:`_window_of_slot`), the slots'
    rows folded in order."""
    nslot = numba.get_num_threads()
    part = np.empty((nslot, 6))
    run_slots(_window_of_slot, nslot, pts, o, r, u, f, near, part, nslot)
    x0, x1, y0, y1, z0, z1 = np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf
    for q in part.tolist():
        x0, x1, y0, y1 = min(x0, q[0]), max(x1, q[1]), min(y0, q[2]), max(y1, q[3])
        z0, z1 = min(z0, q[4]), max(z1, q[5])
    return x0, x1, y0, y1, z0, z1


def fit_grid_view(light, pts: np.ndarray, grid: int, lo, hi, window=None, toward=None) -> View:
    """The light view of the grid: from the light centre (``light_frame``: along the rectangle's
    normal; for the sphere toward ``toward`` or the samples' box centre, below), its window fitted
    to the samples in front of it (one pass, no temporary arrays). ``window``: (x0, x1, y0, y1, z0, z1) of the
    samples with z > 0 and their smallest z in the frame ``light_frame(light, toward)`` (for the
    sphere, ``toward`` is a point known before the samples: the scene's box centre), when the
    caller has them already (:func:`error_bound_samples`); used, with that frame, when every
    sample lies beyond the near plane (then they are the same samples: the same bits as
    :func:`_window_of`), else the frame toward the samples' box centre and a pass over them. V does
    not depend on the frame (the grid's cells, bins and slices only decide which samples each
    test visits; every sample's sums run in the same order)."""
    if len(pts) == 0:
        return light_view(light, np.zeros((1, 3)), grid, grid)
    near = 1e-6 * max(float(np.linalg.norm(hi - lo)), 1e-12)
    if window is not None and window[6] > near:
        r, u, f = light_frame(light, toward=toward)  # the frame the window was measured in
        x0, x1, y0, y1, _z0, z1 = window[:6]
    else:
        r, u, f = light_frame(light, toward=(lo + hi) / 2)
        x0, x1, y0, y1, _z0, z1 = _window_of(pts, light.center, r, u, f, near)
    if not np.isfinite(x0):
        return light_view(light, pts, grid, grid)
    mx, my = 1e-3 * (x1 - x0) + 1e-12, 1e-3 * (y1 - y0) + 1e-12
    return View(light.center.copy(), r, u, f, (x0 - mx, x1 + mx, y0 - my, y1 + my), near, z1 * 1.02, grid, grid)


def cell_numbers(gx: int, gy: int, B: int, nbx: int) -> tuple[np.ndarray, np.ndarray]:
    """(rx (gx,), ry (gy,)): cell (cx, cy) is number rx[cx] + ry[cy] in bin-major order, i.e.
    (bin * B * B + cell in bin) with bin = (cy // B) * nbx + cx // B and cell in bin =
    (cy % B) * B + cx % B (``SampleGrid``)."""
    cx, cy = np.arange(gx, dtype=np.int64), np.arange(gy, dtype=np.int64)
    return (cx // B) * (B * B) + cx % B, (cy // B) * (nbx * B * B) + (cy % B) * B


def build_sample_grid(light, pts: np.ndarray, grid: int, bins: int, slices: int, bounds=None) -> SampleGrid:
    """Step (a): insert every eye sample into the light-view grid by a counting sort (O(n)) and record
    each screen bin's maximum receiver distance (used by the coarse penumbra step). ``bounds``: the
    samples' :class:`SampleBounds` when the caller has them already (:func:`error_bound_samples`)."""
    n = len(pts)
    if bounds is None:
        lo, hi, d0, d1 = _extent(pts, np.asarray(light.center, np.float64))
        view = fit_grid_view(light, pts, grid, lo, hi)
    else:
        lo, hi, d0, d1 = bounds.extent
        view = fit_grid_view(light, pts, grid, lo, hi, bounds.window, bounds.toward)
    vp = view.params()
    nbx = nby = -(-grid // bins)
    dlo = max(d0 * (1 - 1e-9), 1e-12)
    dhi = max(d1 * (1 + 1e-9), dlo * (1 + 1e-9))
    key = np.empty(n, np.int64)
    near = view.near
    sb = slice_bounds(dlo, dhi, slices)
    rx, ry = cell_numbers(grid, grid, bins, nbx)
    count = len(sb) <= _COUNT_SLICES_MAX and not np.isnan(sb).any()
    sc = np.empty((numba.get_num_threads(), _KEY_ROWS, _KEY_CHUNK))
    run_threads(_sample_keys_slot, pts, vp, grid, grid, rx, ry, slices, sb, near, count, key, sc, work_counter())
    start, order, sx, sy, sp, sd = sort_samples(key, pts, vp, nbx * nby * bins * bins * slices)
    m = len(order)
    cbox, cmax, occ = _column_boxes(start, sp, sd, slices)
    bmax = cmax.reshape(nbx * nby, bins * bins).max(axis=1)
    return SampleGrid(
        vp,
        grid,
        grid,
        bins,
        nbx,
        nby,
        slices,
        dlo,
        dhi,
        sb,
        start,
        sx,
        sy,
        sp,
        sd,
        order,
        bmax,
        float(sd.max()) if m else 0.0,
        cbox,
        int(occ[:, 0].sum()),
        int(occ[:, 1].max()) if len(occ) else 0,
    )


# ---------------------------------------------------------------------------------------------
# which occluder triangles are counted
# ---------------------------------------------------------------------------------------------
def _topology(flat):
    """Per scene (cached): occluder faces, their welded adjacency and the per-face 'sheet' flag
    (connected component with more than SOLID_MAX_BOUNDARY boundary edges)."""
    hit = flat._cache.get("irregular_topology")
    if hit is not None:
        return hit
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    occ = np.ascontiguousarray(flat.faces[flat.occluder])
    adj = build_adjacency(flat.vertices, occ)
    F = len(occ)
    sheet = np.zeros(F, bool)
    if F:
        grp_edge = np.repeat(np.arange(adj.n_edges), adj.count)
        first = adj.edge_faces[adj.offsets[:-1]][grp_edge]
        g = coo_matrix((np.ones(len(first)), (first, adj.edge_faces)), shape=(F, F))
        ncomp, comp = connected_components(g, directed=False)
        ecomp = comp[adj.edge_faces[adj.offsets[:-1]]]
        n_e = np.bincount(ecomp, minlength=ncomp)
        n_b = np.bincount(ecomp, weights=(adj.count == 1).astype(float), minlength=ncomp)
        sheet = (n_b > SOLID_MAX_BOUNDARY * n_e)[comp]
        # third vertex and orientation of every (edge, face) entry of the CSR
        f = occ[adj.edge_faces]
        rf = adj.rep[f]
        lo = np.repeat(adj.edges[:, 0], adj.count)
        hi = np.repeat(adj.edges[:, 1], adj.count)
        third = np.where(
            (rf[:, 0] != lo) & (rf[:, 0] != hi),
            f[:, 0],
            np.where((rf[:, 1] != lo) & (rf[:, 1] != hi), f[:, 1], f[:, 2]),
        )
        # +1 when lo -> hi follows the face's winding
        fw = (
            ((rf[:, 0] == lo) & (rf[:, 1] == hi))
            | ((rf[:, 1] == lo) & (rf[:, 2] == hi))
            | ((rf[:, 2] == lo) & (rf[:, 0] == hi))
        )
        orient = np.where(fw, 1, -1)
    else:
        third = np.zeros(0, np.int64)
        orient = np.zeros(0, np.int64)
    hit = (occ, adj, sheet, third, orient)
    flat._cache["irregular_topology"] = hit
    return hit


def facing_and_counted(flat, center) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(occluder faces (F,3), facing the light centre (F,), counted (F,))."""
    occ, _adj, sheet, _t, _o = _topology(flat)
    fr = facing(flat.vertices, occ, center) if len(occ) else np.zeros(0, bool)
    return occ, fr, fr | sheet


def counted_faces(flat, center) -> tuple[np.ndarray, np.ndarray]:
    """(occluder faces (F,3), counted (F,) bool): a triangle is counted when it faces the light
    centre or belongs to a sheet (open component); every count and edge below refers to these."""
    occ, _fr, counted = facing_and_counted(flat, center)
    return occ, counted


# ---------------------------------------------------------------------------------------------
# (b) umbrae: exact depth complexity between each sample and the light centre
# ---------------------------------------------------------------------------------------------
@kernel(inline=True)
def _project(vp, x, y, z):
    dx, dy, dz = x - vp[VP_ORIGIN], y - vp[VP_ORIGIN + 1], z - vp[VP_ORIGIN + 2]
    vx = dx * vp[VP_RIGHT] + dy * vp[VP_RIGHT + 1] + dz * vp[VP_RIGHT + 2]
    vy = dx * vp[VP_UP] + dy * vp[VP_UP + 1] + dz * vp[VP_UP + 2]
    vz = dx * vp[VP_FORWARD] + dy * vp[VP_FORWARD + 1] + dz * vp[VP_FORWARD + 2]
    return vx / vz, vy / vz, vz


@kernel(inline=True)
def _cell_range(x0, x1, y0, y1, vp, gx, gy):
    """Cells (cx0, cx1, cy0, cy1), inclusive, overlapped by the image-plane box; empty when cx0 > cx1."""
    l, r, b, t = vp[VP_L], vp[VP_R], vp[VP_B], vp[VP_T]
    fx0 = np.floor((x0 - l) / (r - l) * gx)
    fx1 = np.floor((x1 - l) / (r - l) * gx)
    fy0 = np.floor((t - y1) / (t - b) * gy)
    fy1 = np.floor((t - y0) / (t - b) * gy)
    if not (fx1 >= 0.0 and fy1 >= 0.0 and fx0 <= gx - 1.0 and fy0 <= gy - 1.0):
        return 1, 0, 1, 0
    return int(max(fx0, 0.0)), int(min(fx1, gx - 1.0)), int(max(fy0, 0.0)), int(min(fy1, gy - 1.0))


@kernel(nogil=True)
def _triangle_setup(verts, faces, counted, vp, center, tri2d, tribox, trid, valid):
    """Light-view image-plane vertices, box and lower bound of the distance to the light centre
    (the distance of the triangle's plane) of every counted triangle."""
    for f in range(faces.shape[0]):
        valid[f] = False
        if not counted[f]:
            continue
        ok = True
        for j in range(3):
            v = faces[f, j]
            x, y, z = _project(vp, verts[v, 0], verts[v, 1], verts[v, 2])
            if not (z > 0.0):
                ok = False
            tri2d[f, 2 * j] = x
            tri2d[f, 2 * j + 1] = y
        if not ok:
            continue
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        e1x, e1y, e1z = verts[b, 0] - verts[a, 0], verts[b, 1] - verts[a, 1], verts[b, 2] - verts[a, 2]
        e2x, e2y, e2z = verts[c, 0] - verts[a, 0], verts[c, 1] - verts[a, 1], verts[c, 2] - verts[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        if nn == 0.0:
            continue
        valid[f] = True
        trid[f] = (
            abs(nx * (verts[a, 0] - center[0]) + ny * (verts[a, 1] - center[1]) + nz * (verts[a, 2] - center[2])) / nn
        )
        tribox[f, 0] = min(tri2d[f, 0], tri2d[f, 2], tri2d[f, 4])
        tribox[f, 1] = max(tri2d[f, 0], tri2d[f, 2], tri2d[f, 4])
        tribox[f, 2] = min(tri2d[f, 1], tri2d[f, 3], tri2d[f, 5])
        tribox[f, 3] = max(tri2d[f, 1], tri2d[f, 3], tri2d[f, 5])


@kernel(nogil=True)
def _triangles_by_bin(tribox, valid, vp, gx, gy, B, nbx, n_bins):
    """(start (n_bins + 1), items): per screen bin, the valid triangles whose box overlaps it,
    ascending; bin b's are ``items[start[b]:start[b + 1]]``. A counting sort by bin in two passes
    over the triangles: count per bin (each triangle's range of bins kept), prefix sum, fill (no
    pair list, no atomics)."""
    F = tribox.shape[0]
    start = np.zeros(n_bins + 1, np.int64)
    rng = np.empty((F, 4), np.int64)  # the bins (by0, by1, bx0, bx1), exclusive ends; empty: 0, 0, 0, 0
    for f in range(F):
        rng[f, 0] = rng[f, 1] = rng[f, 2] = rng[f, 3] = 0
        if valid[f]:
            cx0, cx1, cy0, cy1 = _cell_range(tribox[f, 0], tribox[f, 1], tribox[f, 2], tribox[f, 3], vp, gx, gy)
            if cx0 > cx1 or cy0 > cy1:
                continue
            rng[f, 0], rng[f, 1], rng[f, 2], rng[f, 3] = cy0 // B, cy1 // B + 1, cx0 // B, cx1 // B + 1
            for by in range(rng[f, 0], rng[f, 1]):
                for bx in range(rng[f, 2], rng[f, 3]):
                    start[by * nbx + bx + 1] += 1
    for b in range(n_bins):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(start[n_bins], np.int64)
    for f in range(F):
        for by in range(rng[f, 0], rng[f, 1]):
            for bx in range(rng[f, 2], rng[f, 3]):
                i = by * nbx + bx
                items[fill[i]] = f
                fill[i] += 1
    return start, items


def _pairs_by_bin(counts, pair_bin, n_bins):
    """Item-major (item, bin) pairs -> per-bin item lists (items ascending within a bin)."""
    offs = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(counts, out=offs[1:])
    item = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    start, order = counting_sort(pair_bin, n_bins)
    return start, item[order]


def bins_by_work(bin_start, g_start, cells_per_bin, also_empty: bool = False):
    """The bins that have items, by estimated work (items x samples of the bin), largest first.
    The umbra and penumbra kernels run one worker per thread, each taking the next bin of this list
    from a shared atomic counter (:func:`next_item`) until none is left: greedy list scheduling,
    largest first, on the bins' real times (a static split by the estimate left one thread up to
    27% over the other). Each bin's own computation, and so V, does not depend on the order.
    NumPy, not a kernel: Numba's stable sort alone took ~2 s to compile. With ``also_empty``, then
    the bins that hold samples but no items, in index order (the penumbra pass composes V per bin)."""
    bin_start = np.asarray(bin_start, np.int64)
    edges = np.asarray(g_start, np.int64)[:: int(cells_per_bin)][: len(bin_start)]
    items = np.diff(bin_start)
    samples = np.diff(edges)
    work = items * (samples + 1.0)
    order = np.argsort(-work, kind="stable")[: int(np.count_nonzero(items > 0))]
    if also_empty:
        order = np.concatenate([order, np.flatnonzero((items == 0) & (samples > 0))])
    return order


@kernel(inline=True)
def _tie(dx, dy):
    return dy > 0.0 or (dy == 0.0 and dx > 0.0)


@kernel(nogil=True, nrt=False)
def _umbra_kernel(
    _worker,
    g_start,
    sx,
    sy,
    sp,
    sd,
    gx,
    gy,
    B,
    nbx,
    S,
    sb,
    vp,
    center,
    verts,
    faces,
    tri2d,
    trid,
    bin_start,
    bin_items,
    umbra,
    tests,
    bin_order,
    counter,
    keep,
    cand,
):
    """One worker of the umbra pass (:func:`count_umbrae`), run by ``run_slots``, one per thread: takes
    the next bin of ``bin_order`` (``next_item``) until none is left. ``keep``, ``cand``: scratch,
    one row per worker (a cell column's flags; a triangle's candidates in the bin)."""
    w = _worker
    keep_w, cand_w = keep[w], cand[w]  # this worker's scratch rows, once
    while True:
        q = next_item(counter)
        if q >= bin_order.shape[0]:
            break
        bi = bin_order[q]
        by = bi // nbx
        bx = bi % nbx
        ntest = 0
        for kk in range(bin_start[bi], bin_start[bi + 1]):
            f = bin_items[kk]
            ax, ay, bx2, by2, cx2, cy2 = (
                tri2d[f, 0],
                tri2d[f, 1],
                tri2d[f, 2],
                tri2d[f, 3],
                tri2d[f, 4],
                tri2d[f, 5],
            )
            area = (bx2 - ax) * (cy2 - ay) - (by2 - ay) * (cx2 - ax)
            if area == 0.0:
                continue
            cx0, cx1, cy0, cy1 = _cell_range(
                min(ax, bx2, cx2), max(ax, bx2, cx2), min(ay, by2, cy2), max(ay, by2, cy2), vp, gx, gy
            )
            cx0 = max(cx0, bx * B)
            cx1 = min(cx1, bx * B + B - 1)
            cy0 = max(cy0, by * B)
            cy1 = min(cy1, by * B + B - 1)
            s0 = slice_of(trid[f], sb)
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            nx = (verts[i1, 1] - verts[i0, 1]) * (verts[i2, 2] - verts[i0, 2]) - (verts[i1, 2] - verts[i0, 2]) * (
                verts[i2, 1] - verts[i0, 1]
            )
            ny = (verts[i1, 2] - verts[i0, 2]) * (verts[i2, 0] - verts[i0, 0]) - (verts[i1, 0] - verts[i0, 0]) * (
                verts[i2, 2] - verts[i0, 2]
            )
            nz = (verts[i1, 0] - verts[i0, 0]) * (verts[i2, 1] - verts[i0, 1]) - (verts[i1, 1] - verts[i0, 1]) * (
                verts[i2, 0] - verts[i0, 0]
            )
            num = nx * (verts[i0, 0] - center[0]) + ny * (verts[i0, 1] - center[1]) + nz * (verts[i0, 2] - center[2])
            sg = 1.0 if area > 0.0 else -1.0
            # tie rule: a point on an edge belongs to the triangle that traverses the edge (in its
            # counter-clockwise orientation) upward, or rightward when horizontal; two triangles
            # sharing the edge traverse it in opposite directions, so exactly one counts the point
            t0 = _tie(sg * (bx2 - ax), sg * (by2 - ay))
            t1 = _tie(sg * (cx2 - bx2), sg * (cy2 - by2))
            t2 = _tie(sg * (ax - cx2), sg * (ay - cy2))
            # first the point-in-triangle test on the image-plane coordinates, branch-free (it
            # vectorizes), the samples inside compacted into ``cand``; then the plane test for them
            m = 0
            for cy in range(cy0, cy1 + 1):
                for cx in range(cx0, cx1 + 1):
                    col = (bi * B * B + (cy - by * B) * B + cx - bx * B) * S  # cy % B = cy - by B: no division
                    j0, j1 = g_start[col + s0], g_start[col + S]
                    ntest += j1 - j0
                    for i in range(j1 - j0):
                        j = np.uint64(j0 + i)
                        px, py = sx[j], sy[j]
                        e0 = sg * ((bx2 - ax) * (py - ay) - (by2 - ay) * (px - ax))
                        e1 = sg * ((cx2 - bx2) * (py - by2) - (cy2 - by2) * (px - bx2))
                        e2 = sg * ((ax - cx2) * (py - cy2) - (ay - cy2) * (px - cx2))
                        k0 = (e0 > 0.0) | ((e0 == 0.0) & t0)
                        k1 = (e1 > 0.0) | ((e1 == 0.0) & t1)
                        k2 = (e2 > 0.0) | ((e2 == 0.0) & t2)
                        keep[w, np.uint64(i)] = np.int8(k0) & np.int8(k1) & np.int8(k2)
                    m = compact_indices(keep_w, j1 - j0, j0, cand_w, m)
            for i in range(m):  # branch-free (den == 0: th is inf or NaN, and the test fails)
                j = np.uint64(cand[w, i])
                den = nx * (sp[j, 0] - center[0]) + ny * (sp[j, 1] - center[1]) + nz * (sp[j, 2] - center[2])
                th = num / den  # the triangle's plane along centre -> p, 1 at p
                umbra[j] += np.int32((den != 0.0) & (th > 0.0) & (th < 1.0))
        tests[bi] = ntest


def count_umbrae(grid: SampleGrid, verts, faces, counted, center) -> tuple[np.ndarray, dict]:
    """Step (b): per sample, the number of counted triangles crossed by the segment sample -> light
    centre (hard irregular shadow mapping, counting depth complexity): every triangle is projected
    to the light image plane and tested exactly against the stored coordinates of the samples of
    the cells its box covers (only slices beyond the triangle's plane distance)."""
    return start_umbrae(grid, verts, faces, counted, center).finish()


def start_umbrae(grid: SampleGrid, verts, faces, counted, center):
    """:func:`count_umbrae` started: the triangles' set-up and binning, then the kernel's bins, taken
    by the slot threads (``start_slots``) while the calling thread is free for other work (the
    silhouettes and quads of step (c), :func:`irregular_visibility`) until it calls the launch's
    ``finish()``, takes the bins that are left and gets (umbra, stats). The set-up is made once, by
    the first slot to start (a slot thread, or the calling thread at ``finish()`` when it has none),
    under a lock that the other slots wait on: it ran on the calling thread alone before, ~0.4 ms
    with the slot thread idle. Every bin's counts are its own, so the result does not depend on who
    took it."""
    F = len(faces)
    c = np.asarray(center, np.float64)
    umbra = np.zeros(len(grid.order), np.int32)
    tests = np.zeros(grid.n_bins, np.int64)
    nw = numba.get_num_threads()
    max_col, max_bin = grid.max_column, grid.max_bin
    lock = threading.Lock()
    prep = {}

    def prepared():
        with lock:
            if not prep:
                try:
                    tri2d = np.zeros((F, 6))
                    tribox = np.zeros((F, 4))
                    trid = np.zeros(F)
                    valid = np.zeros(F, bool)
                    _triangle_setup(verts, faces, counted, grid.vp, c, tri2d, tribox, trid, valid)
                    bstart, bitems = _triangles_by_bin(
                        tribox, valid, grid.vp, grid.gx, grid.gy, grid.bins, grid.nbx, grid.n_bins
                    )
                    order = bins_by_work(bstart, grid.start, grid.bins * grid.bins * grid.slices)
                    prep.update(tri2d=tri2d, trid=trid, valid=valid, bstart=bstart, bitems=bitems, order=order)
                except BaseException as exc:  # every slot raises it (none waits for a set-up that failed)
                    prep["error"] = exc
        if "error" in prep:
            raise prep["error"]
        return prep

    counter = work_counter()
    col_scratch = np.empty((nw, max(max_col, 1)), np.int8)
    bin_scratch = np.empty((nw, max(max_bin, 1) + 8), np.int64)  # (compact_indices writes 8 at a time)

    def slot_fn(slot):
        q = prepared()
        _umbra_kernel(
            slot,
            grid.start,
            grid.ix,
            grid.iy,
            grid.pos,
            grid.dist,
            grid.gx,
            grid.gy,
            grid.bins,
            grid.nbx,
            grid.slices,
            grid.sbound,
            grid.vp,
            c,
            verts,
            faces,
            q["tri2d"],
            q["trid"],
            q["bstart"],
            q["bitems"],
            umbra,
            tests,
            q["order"],
            counter,
            col_scratch,
            bin_scratch,
        )

    def result():
        q = prepared()
        return (
            umbra,
            {
                "umbra_triangles": int(q["valid"].sum()),
                "umbra_skipped_triangles": int((counted & ~q["valid"]).sum()),
                "umbra_tri_bin_pairs": len(q["bitems"]),
                "umbra_sample_tests": int(tests.sum()),
            },
        )

    return start_slots(slot_fn, nw, result=result)


# ---------------------------------------------------------------------------------------------
# silhouettes
# ---------------------------------------------------------------------------------------------
@dataclass
class Edges:
    """Edges that carry penumbral occlusion: endpoints and, per edge, the third vertices of its
    counted adjacent triangles (CSR), whose side decides the sign at each sample."""

    a: np.ndarray  # (E,3)
    b: np.ndarray  # (E,3)
    tv_start: np.ndarray  # (E+1,)
    tv: np.ndarray  # (M,3)

    def __len__(self) -> int:
        return len(self.a)


def fold_candidates(flat, counted, lo, hi, center, radius) -> np.ndarray:
    """(E,) bool over the adjacency's edges: manifold edges whose two adjacent triangles are both
    counted and that can be a fold (one triangle facing p, the other not) for a receiver p in the
    edge's shadow; elsewhere the two triangles' terms are equal and opposite at every sample (they
    cancel exactly), so dropping the edge changes no bit. An edge is kept when both hold:

    * some corner configuration of the receivers' box [lo, hi] is not on one common side of both
      planes (else no receiver sees a fold), and
    * one of the triangles is within the light's angular radius of grazing as seen from the edge:
      a receiver shadowed through o sees o along a direction within asin(r / |o - c|) of (o - c),
      so a plane at distance h from the centre can separate two such receivers' views only if
      h / max(|a - c|, |b - c|) <= r / dmin (dmin: distance from the centre to the edge).
    """
    _occ, adj, _sheet, _t, _o = _topology(flat)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float64)
    out = np.zeros(adj.n_edges, np.bool_)
    run_threads(
        _fold_slot,
        adj.count,
        adj.edges,
        adj.edge_faces,
        adj.offsets,
        counted,
        flat.vertices,
        adj.normals,
        adj.anchors,
        np.asarray(center, np.float64),
        float(radius),
        corners,
        out,
    )
    return out


@kernel(inline=True)
def _plane_h(normals, anchors, f, c):
    """|n . (anchor - c)| / |n|: the distance from c to face f's plane."""
    n0, n1, n2 = normals[f, 0], normals[f, 1], normals[f, 2]
    num = abs(n0 * (anchors[f, 0] - c[0]) + n1 * (anchors[f, 1] - c[1]) + n2 * (anchors[f, 2] - c[2]))
    return num / max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)


@kernel(inline=True)
def _box_side(normals, anchors, f, corners):
    """+1 / -1 when every corner of the box is strictly above / below face f's plane, else 0."""
    n0, n1, n2 = normals[f, 0], normals[f, 1], normals[f, 2]
    d = n0 * anchors[f, 0] + n1 * anchors[f, 1] + n2 * anchors[f, 2]
    pos = True
    neg = True
    for k in range(corners.shape[0]):
        s = (n0 * corners[k, 0] + n1 * corners[k, 1] + n2 * corners[k, 2]) - d
        pos = pos and s > 0.0
        neg = neg and s < 0.0
    return 1 if pos else (-1 if neg else 0)


@kernel(nogil=True, nrt=False, noalias=True)
def _fold_slot(slot, count, edges, edge_faces, offsets, counted, V, normals, anchors, c, radius, corners, out, nslot):
    """:func:`fold_candidates` per manifold edge. Run by ``run_slots``: slot ``slot`` of ``nslot``
    takes one contiguous block of the edges."""
    E = count.shape[0]
    e0, e1 = np.uint64(slot * E // nslot), np.uint64((slot + 1) * E // nslot)  # unsigned: see _sample_keys_slot
    for e in range(e0, e1):
        if count[e] != 2:
            continue
        f0 = edge_faces[offsets[e]]
        f1 = edge_faces[offsets[e] + 1]
        if not (counted[f0] and counted[f1]):
            continue
        a0, a1, a2 = V[edges[e, 0], 0], V[edges[e, 0], 1], V[edges[e, 0], 2]
        b0, b1, b2 = V[edges[e, 1], 0], V[edges[e, 1], 1], V[edges[e, 1], 2]
        u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
        t = ((c[0] - a0) * u0 + (c[1] - a1) * u1 + (c[2] - a2) * u2) / max(u0 * u0 + u1 * u1 + u2 * u2, 1e-300)
        t = min(max(t, 0.0), 1.0)
        q0, q1, q2 = a0 + t * u0 - c[0], a1 + t * u1 - c[1], a2 + t * u2 - c[2]
        dmin = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        da = np.sqrt((a0 - c[0]) ** 2 + (a1 - c[1]) ** 2 + (a2 - c[2]) ** 2)
        db = np.sqrt((b0 - c[0]) ** 2 + (b1 - c[1]) ** 2 + (b2 - c[2]) ** 2)
        dfar = max(da, db)
        h = min(_plane_h(normals, anchors, f0, c), _plane_h(normals, anchors, f1, c))
        if not ((dmin <= radius) or (h * dmin <= radius * dfar * (1.0 + 1e-6) + 1e-12)):
            continue  # the side test only where it can matter
        s0 = _box_side(normals, anchors, f0, corners)
        s1 = _box_side(normals, anchors, f1, corners)
        out[e] = (s0 == 0) or (s1 == 0) or (s0 != s1)


@kernel
def _select_edges(count, offsets, edge_faces, edges, fa_, fr, counted, orient, third, fold, V):
    """:func:`select_silhouette_edges`' adjacency mode in one pass over the welded edges (ascending):
    an edge is a candidate when it is a silhouette seen from the centre (``silhouette_adjacency``'s
    test: a boundary, or a mix of faces facing it by the face planes), non-manifold, or a fold
    candidate; it is kept when the orientations of its counted triangles seen from the centre do
    not sum to zero, or it is a fold candidate. Returns (a, b, tv_start, tv, the kept fold edges
    whose sum is zero): the endpoints and, per edge, its counted triangles' third vertices in the
    adjacency's order. ``fa_``: each face facing the centre by its plane (``facing_from_planes``,
    as ``silhouette_adjacency``)."""
    E = count.shape[0]
    keep = np.zeros(E, np.bool_)
    n_kept = 0
    n_tv = 0
    n_fold = 0
    for e in range(E):
        s, c = offsets[e], count[e]
        cf = 0
        for k in range(s, s + c):
            cf += fa_[edge_faces[k]]
        if not ((c == 1) or (0 < cf < c) or (c > 2) or fold[e]):
            continue
        w = 0
        nt = 0
        for k in range(s, s + c):
            f = edge_faces[k]
            if counted[f]:
                w += orient[k] if fr[f] else -orient[k]
                nt += 1
        if w != 0 or fold[e]:
            keep[e] = True
            n_kept += 1
            n_tv += nt
            n_fold += w == 0
    a = np.empty((n_kept, 3))
    b = np.empty((n_kept, 3))
    tv_start = np.zeros(n_kept + 1, np.int64)
    tv = np.empty((n_tv, 3))
    i = 0
    t = 0
    for e in range(E):
        if not keep[e]:
            continue
        for d in range(3):
            a[i, d] = V[edges[e, 0], d]
            b[i, d] = V[edges[e, 1], d]
        for k in range(offsets[e], offsets[e] + count[e]):
            if counted[edge_faces[k]]:
                for d in range(3):
                    tv[t, d] = V[third[k], d]
                t += 1
        i += 1
        tv_start[i] = t
    return a, b, tv_start, tv, n_fold


def select_silhouette_edges(
    flat, center, mode: str, folds: bool = True, box=None, radius: float = 0.0, fc=None
) -> tuple[Edges, dict]:
    """Edges that carry penumbral occlusion. ``adjacency``: the silhouette edges seen from the light
    centre (``geometry/silhouette.py``: facing mix or boundary, from the welded adjacency), plus
    non-manifold edges, kept when the counted triangles around them do not cancel (sum of their
    orientations seen from the centre != 0); with ``folds``, also the edges between two counted
    triangles that fold as seen from some receiver (:func:`fold_candidates`, ``box`` = the
    receivers' bounding box), so that the sum over edges equals the sum over counted triangles at
    every sample. ``all-edges``: every edge of every counted triangle, separately (no adjacency)."""
    occ, fr, counted = facing_and_counted(flat, center) if fc is None else fc
    V = flat.vertices
    if mode == "all-edges":
        f = occ[counted]
        a = V[f].reshape(-1, 3)
        b = V[f[:, [1, 2, 0]]].reshape(-1, 3)
        tv = V[f[:, [2, 0, 1]]].reshape(-1, 3)
        E = len(a)
        ed = Edges(
            np.ascontiguousarray(a), np.ascontiguousarray(b), np.arange(E + 1, dtype=np.int64), np.ascontiguousarray(tv)
        )
        return ed, {"silhouette_edges": E, "fold_edges": 0, "counted_triangles": int(counted.sum())}
    _occ, adj, _sheet, third, orient = _topology(flat)
    fold = (
        fold_candidates(flat, counted, box[0], box[1], center, radius)
        if folds and box is not None
        else np.zeros(adj.n_edges, bool)
    )
    a, b, tv_start, tv, n_fold = _select_edges(
        adj.count,
        adj.offsets,
        adj.edge_faces,
        adj.edges,
        facing_from_planes(adj.normals, adj.anchors, center),
        fr,
        counted,
        orient,
        third,
        fold,
        V,
    )
    ed = Edges(a, b, tv_start, tv)
    return ed, {
        "silhouette_edges": int(len(a)) - n_fold,
        "fold_edges": n_fold,
        "counted_triangles": int(counted.sum()),
    }


# ---------------------------------------------------------------------------------------------
# (c) coarse penumbra: one light-view quad per silhouette edge, binned, refined per bin
# ---------------------------------------------------------------------------------------------
#: qd's columns of the sphere's per-sample test (:func:`_arc_setup`, :func:`disk_reach`): the unit
#: normal of the edge's great circle seen from the light centre, the in-plane normals at its two
#: ends (pointing into the arc), the two ends' unit directions, the edge's distance to the centre
_QN, _QGA, _QGB, _QA, _QB, _QDMIN, _QCOLS = 10, 13, 16, 19, 22, 25, 26


@kernel(inline=True)
def _arc_setup(ea, eb, e, center, dmin, qd):
    """Edge e's arc for :func:`disk_reach`: the directions from the light centre to its points form
    the minor great-circle arc from a^ to b^ (the segment misses the centre)."""
    ax, ay, az = ea[e, 0] - center[0], ea[e, 1] - center[1], ea[e, 2] - center[2]
    bx, by, bz = eb[e, 0] - center[0], eb[e, 1] - center[1], eb[e, 2] - center[2]
    la = np.sqrt(ax * ax + ay * ay + az * az)
    lb = np.sqrt(bx * bx + by * by + bz * bz)
    ax, ay, az = ax / la, ay / la, az / la
    bx, by, bz = bx / lb, by / lb, bz / lb
    nx = ay * bz - az * by
    ny = az * bx - ax * bz
    nz = ax * by - ay * bx
    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
    if nn > 0.0:
        nx, ny, nz = nx / nn, ny / nn, nz / nn
    else:  # one direction: no arc interior (both in-arc tests fail), the ends decide
        nx, ny, nz = 0.0, 0.0, 0.0
    qd[e, _QN], qd[e, _QN + 1], qd[e, _QN + 2] = nx, ny, nz
    qd[e, _QGA], qd[e, _QGA + 1], qd[e, _QGA + 2] = ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax
    qd[e, _QGB], qd[e, _QGB + 1], qd[e, _QGB + 2] = by * nz - bz * ny, bz * nx - bx * nz, bx * ny - by * nx
    qd[e, _QA], qd[e, _QA + 1], qd[e, _QA + 2] = ax, ay, az
    qd[e, _QB], qd[e, _QB + 1], qd[e, _QB + 2] = bx, by, bz
    qd[e, _QDMIN] = dmin


#: disk_reach's margins: relative on r / dmin, and absolute (a sine)
_REACH_SLACK = 1e-4
_REACH_EPS = 1e-7


@kernel(inline=True, nrt=False)
def reach_ratio(qd, e, radius):
    """:func:`disk_reach`'s ``rdm``: r / dmin of edge e with its margins (0 where dmin is 0)."""
    d = qd[e, _QDMIN]
    return radius / d * (1.0 + _REACH_SLACK) + _REACH_EPS if d > 0.0 else 0.0


@kernel(inline=True, nrt=False)
def arc_position(ux, uy, uz, arc):
    """Unit direction u against edge e's arc (``arc``: qd's columns from ``_QN`` on, from
    :func:`_arc_setup`): (u . n^, inside the arc's wedge, u . a^, u . b^), branch-free."""
    sn = ux * arc[0] + uy * arc[1] + uz * arc[2]
    ta = ux * arc[3] + uy * arc[4] + uz * arc[5]
    tb = ux * arc[6] + uy * arc[7] + uz * arc[8]
    ca = ux * arc[9] + uy * arc[10] + uz * arc[11]
    cb = ux * arc[12] + uy * arc[13] + uz * arc[14]
    return sn, (ta > 0.0) & (tb > 0.0), ca, cb


@kernel(inline=True, nrt=False)
def disk_reach(ux, uy, uz, iD, radius, rdm, arc):
    """The sphere's per-sample test: can edge e (its arc ``arc`` = qd's columns ``_QN`` on, from
    :func:`_arc_setup`) hide part of the disk facing a sample at unit direction u from the light
    centre c and distance D = 1 / iD? ``rdm`` = r / dmin with margins (``_REACH_SLACK``,
    ``_REACH_EPS``). Angles at c, no image-plane stretch (the quad's bound has the window's).

    An edge point x at distance d >= dmin from c and angle a < 90 deg from u hides part of the
    disk of radius r facing p iff the ray from p through x meets the disk:
    d (D sin a + r cos a) <= r D, so sin a + (r / D) cos a <= r / dmin. That left side grows with a
    up to 90 deg - atan(r / D) and is 1 > r / dmin at 90 deg, so, when every point of the edge lies
    within 90 deg of u (both ends do: the arc is minor), it is smallest at the edge's nearest
    direction to u: in the arc, sin a = |u . n^|; else an end's, cos a = max(u . a^, u . b^). With
    cos a >= cos^2 a = 1 - sin^2 a (no square root): the sample is kept iff
    sqrt(S2) <= rdm - (r / D)(1 - S2), S2 = sin^2 a. Every sample it drops has an exact zero term
    (a relative margin of 1e-4 on r / dmin); with an end 90 deg or more away it keeps the sample."""
    sn = ux * arc[0] + uy * arc[1] + uz * arc[2]
    ca = ux * arc[9] + uy * arc[10] + uz * arc[11]
    cb = ux * arc[12] + uy * arc[13] + uz * arc[14]
    # inside the arc's wedge (arc_position's u . (n^ x a^) > 0 and u . (b^ x n^) > 0): as
    # n^ x a^ = (b^ - (a^ . b^) a^) / |a^ x b^| and b^ x n^ = (a^ - (a^ . b^) b^) / |a^ x b^|, from the
    # ends' cosines (two dot products fewer per sample; at the wedge's planes both branches of s2
    # below agree, so a decision flipped by rounding moves s2 by rounding, within the margins)
    cab = arc[9] * arc[12] + arc[10] * arc[13] + arc[11] * arc[14]
    inarc = (cb - cab * ca > 0.0) & (ca - cab * cb > 0.0)
    cm = ca if ca > cb else cb
    s2 = sn * sn if inarc else 1.0 - cm * cm
    tt = rdm - radius * iD * (1.0 - s2)
    near = np.int8(tt >= 0.0) & np.int8(s2 <= tt * tt)
    return near | np.int8(not ((ca > 0.0) & (cb > 0.0)))


@kernel(inline=True, nrt=False)
def cell_direction(xm, ym, vp):
    """The unit direction from the light centre through image-plane point (xm, ym)."""
    iw = 1.0 / np.sqrt(xm * xm + ym * ym + 1.0)
    return (
        (xm * vp[VP_RIGHT] + ym * vp[VP_UP] + vp[VP_FORWARD]) * iw,
        (xm * vp[VP_RIGHT + 1] + ym * vp[VP_UP + 1] + vp[VP_FORWARD + 1]) * iw,
        (xm * vp[VP_RIGHT + 2] + ym * vp[VP_UP + 2] + vp[VP_FORWARD + 2]) * iw,
    )


@kernel(inline=True, nrt=False)
def disk_cell_reach(mx, my, mz, chd, shd, arc, rdm, radius, iDb):
    """:func:`disk_reach` for a whole cell column (m: the unit direction through its image-plane
    centre, :func:`cell_direction`; hd its half diagonal, ``chd``, ``shd`` = its cosine and sine,
    rounded up) up to distance 1 / ``iDb``: (applies, entry). Every sample direction of the cell
    lies within the angle hd of m (the image plane's stretch is >= 1), so its angle to the edge's
    arc is at least a_lb = a_m - hd; the test's left side sin a + (r/D) cos a grows with a (while
    < 1) and falls with D, so lower bounds of sin a_lb and cos a_lb bound it for every sample
    (in the arc, 1 - sin^2 a_m <= cos a_m <= 1: no square root). ``applies`` is False when an end of the edge may lie 90 deg or more from a sample of the
    cell (the caller then uses the quad); else ``entry`` is the distance from which a sample of the
    cell can pass, r cos a_lb / (r/dmin - sin a_lb) (the wedge's entry), or -1 when none up to
    1 / iDb can."""
    sn, inarc, ca, cb = arc_position(mx, my, mz, arc)
    # branch-free, one select per statement, so that a loop of it vectorizes (disk_cells_reach)
    applies = (ca > shd) & (cb > shd)
    cm = ca if ca > cb else cb
    q = np.sqrt(max(1.0 - cm * cm, 0.0))
    s_lo = abs(sn) if inarc else q
    c_lo = 1.0 - sn * sn if inarc else cm
    c_hi = 1.0 if inarc else cm
    s1 = max(s_lo * chd - c_hi * shd, 0.0)
    c1 = c_lo * chd + s_lo * shd
    passes = s1 + radius * iDb * c1 <= rdm
    entry = radius * c1 / (rdm - s1)
    entry = entry if passes else -1.0
    return applies, (entry if applies else -1.0)


@kernel(inline=True, nrt=False)
def disk_cells_reach(mdir, n, chd, shd, arc, rdm, radius, iDb, app, ent):
    """:func:`disk_cell_reach` of the n cells whose directions are ``mdir[:, :n]`` (a bin's), into
    ``app`` (1.0 where it applies) and ``ent`` (the entry, -1 where none), in one loop (it
    vectorizes: ``disk_cell_reach`` is branch-free); the penumbra pass visited each cell with a
    chain of branches and square roots instead."""
    for lc in range(n):
        applies, entry = disk_cell_reach(mdir[0, lc], mdir[1, lc], mdir[2, lc], chd, shd, arc, rdm, radius, iDb)
        ent[lc] = entry
        app[lc] = 1.0 if applies else 0.0


@kernel
def _quad_setup(ea, eb, vp, center, radius, shape, nrm_l, dmax, qd):
    """Per edge: image-plane endpoints, the minimum distance of the edge to the light centre and the
    stretch factor of the image plane along the footprint (qd[e] = ax ay bx by dmin stretch valid)."""
    for e in range(ea.shape[0]):
        ax, ay, az = _project(vp, ea[e, 0], ea[e, 1], ea[e, 2])
        bx, by, bz = _project(vp, eb[e, 0], eb[e, 1], eb[e, 2])
        qd[e, 0] = ax
        qd[e, 1] = ay
        qd[e, 2] = bx
        qd[e, 3] = by
        # distance from the centre to the segment
        ux, uy, uz = eb[e, 0] - ea[e, 0], eb[e, 1] - ea[e, 1], eb[e, 2] - ea[e, 2]
        wx, wy, wz = center[0] - ea[e, 0], center[1] - ea[e, 1], center[2] - ea[e, 2]
        uu = ux * ux + uy * uy + uz * uz
        tt = 0.0 if uu == 0.0 else min(max((wx * ux + wy * uy + wz * uz) / uu, 0.0), 1.0)
        qx, qy, qz = wx - tt * ux, wy - tt * uy, wz - tt * uz
        dmin = np.sqrt(qx * qx + qy * qy + qz * qz)
        # kappa bounds |x . o^| / r over light points x and occluder directions o^ that matter: the
        # sphere's disk is perpendicular to the direction c -> p, within the footprint angle of o^;
        # the rectangle lies in its plane (largest sine of an endpoint direction to its normal)
        kappa = 1.0
        if shape == 1:
            if dmin > radius:
                kappa = min(1.0, np.sin(np.arctan(radius * (1.0 / (dmin - radius) - 1.0 / dmax))) * (1.0 + _SLACK))
        else:
            kappa = 0.0
            for px, py, pz in ((ea[e, 0], ea[e, 1], ea[e, 2]), (eb[e, 0], eb[e, 1], eb[e, 2])):
                dx, dy, dz = px - center[0], py - center[1], pz - center[2]
                dn = np.sqrt(dx * dx + dy * dy + dz * dz)
                cs = abs(dx * nrm_l[0] + dy * nrm_l[1] + dz * nrm_l[2]) / dn
                kappa = max(kappa, np.sqrt(max(1.0 - cs * cs, 0.0)))
            kappa = min(1.0, kappa * (1.0 + _SLACK) + 1e-9)
        # stored as an effective distance: dmin - kappa r + r, so that quad_half_width's (d - r) is
        # (dmin - kappa r)
        qd[e, 4] = dmin - kappa * radius + radius
        qd[e, 5] = max(ax * ax + ay * ay, bx * bx + by * by)
        valid = az > 0.0 and bz > 0.0 and np.isfinite(ax) and np.isfinite(bx)
        qd[e, 6] = 1.0 if valid else 0.0
        # the rectangle (in the view's z = 0 plane): 1 / the edge's smallest view depth (see rect_reach)
        qd[e, 7] = 1.0 / min(az, bz) if (valid and shape == 0) else 0.0
        if shape == 1:
            _arc_setup(ea, eb, e, center, dmin, qd)


@kernel(inline=True)
def quad_half_width(qd, e, radius, dmax, corner2):
    """Half-width R of edge e's penumbra quad (image-plane units) for receivers up to distance
    ``dmax`` from the light centre: an occluder point at distance d shadows receivers within the
    angle atan(r (1/(d - kappa r) - 1/D)) of it (r: radius of the light's bounding sphere, kappa: see
    _quad_setup; qd stores d - kappa r + r); x the image
    plane's stretch 1/cos^2 of the largest angle off the view axis among the edge's endpoints and the
    box the receivers lie in (``corner2``: its largest squared image-plane radius). inf when the
    light's sphere reaches the edge, <= 0 when no receiver can be hit."""
    dmin = qd[e, 4]
    if dmin <= radius:
        return np.inf
    return (1.0 + max(qd[e, 5], corner2)) * radius * (1.0 / (dmin - radius) - 1.0 / dmax) * (1.0 + _SLACK) + 1e-12


#: absolute margin of the rectangle's bounds (image-plane units), as quad_half_width's 1e-12
_EPS_IMG = 1e-12


@kernel(inline=True)
def rect_k(qd, e, dmax):
    """The rectangle light: the largest k = 1/z_min - 1/z (z: view depth, z_min: the edge's smallest)
    of receivers up to distance ``dmax`` (their depth is at most their distance), with a relative
    slack of ``_SLACK``; < 0 when no receiver lies beyond the edge."""
    return (qd[e, 7] - 1.0 / dmax) * (1.0 + _SLACK)


@kernel(inline=True)
def rect_reach(qd, e, x0, x1, y0, y1):
    """The rectangle light's exact penumbra region of edge e, against an image-plane box: the
    smallest k at which the box meets the region of receivers with k = 1/z_min - 1/z.

    The view looks from the light centre c along the rectangle's normal, so the rectangle lies in
    its z = 0 plane, and in image coordinates (x/z, y/z) it is the box [-hx, hx] x [-hy, hy] (qd's
    columns 8, 9: ``build_penumbra_quads``). A receiver p (depth z) gets a nonzero term only if some
    edge point q in front of it (depth z_q < z) lies on a segment from a light point x to p (the
    edge's projection from p meets the rectangle); then image(p) = image(q) - (1/z_q - 1/z) x_xy,
    and since 1/z_q - 1/z <= k and the box is symmetric, image(p) lies in the segment A'B' swept by
    the box scaled by k: a hexagon, convex, whose sides are parallel to the image axes and to A'B'.
    So the box misses it for every k below the largest, over those three separating axes, of
    (centre distance - the box's extent - the segment's) / the light box's extent; both grown by
    ``_EPS_IMG``. Exact, unlike the circumscribed circle (``quad_half_width``), and without its
    stretch: 3.6x fewer candidate samples on ``bunny``."""
    ax, ay, bx, by, hx, hy = qd[e, 0], qd[e, 1], qd[e, 2], qd[e, 3], qd[e, 8], qd[e, 9]
    sx, sy = bx - ax, by - ay
    wx, wy = 0.5 * (x1 - x0), 0.5 * (y1 - y0)
    dx, dy = 0.5 * (x0 + x1 - ax - bx), 0.5 * (y0 + y1 - ay - by)
    kx = (abs(dx) - wx - 0.5 * abs(sx) - _EPS_IMG) / hx
    ky = (abs(dy) - wy - 0.5 * abs(sy) - _EPS_IMG) / hy
    # across A'B' (normal (-sy, sx), not normalised: both sides scale alike)
    hn = hx * abs(sy) + hy * abs(sx)
    kn = (abs(sx * dy - sy * dx) - wx * abs(sy) - wy * abs(sx) - _EPS_IMG * (abs(sx) + abs(sy))) / hn
    kn = kn if hn > 0.0 else -np.inf  # a point segment: the box axes decide
    return max(kx, ky, kn)


@kernel(inline=True)
def quad_axes(qd, e, R):
    """The quad of edge e with half-width R (finite, > 0) as a centred box on its own axes: (unit
    direction ux, uy; centre cx, cy; half-length, half-width)."""
    ax, ay, bx, by = qd[e, 0], qd[e, 1], qd[e, 2], qd[e, 3]
    dx, dy = bx - ax, by - ay
    ln = np.sqrt(dx * dx + dy * dy)
    if ln > 0.0:
        ux, uy = dx / ln, dy / ln
    else:
        ux, uy = 1.0, 0.0
    return ux, uy, 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * ln + R, R


@kernel(inline=True)
def axes_overlap_box(ux, uy, cx, cy, hl, hw, x0, x1, y0, y1):
    """Separating-axis test of a quad given by :func:`quad_axes` against an image-plane box."""
    hx, hy = 0.5 * (x1 - x0), 0.5 * (y1 - y0)
    mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    # box axes
    if abs(mx - cx) > hx + hl * abs(ux) + hw * abs(uy):
        return False
    if abs(my - cy) > hy + hl * abs(uy) + hw * abs(ux):
        return False
    # quad axes
    if abs((mx - cx) * ux + (my - cy) * uy) > hl + hx * abs(ux) + hy * abs(uy):
        return False
    return abs(-(mx - cx) * uy + (my - cy) * ux) <= hw + hx * abs(uy) + hy * abs(ux)


@kernel(inline=True)
def box_corner2(x0, x1, y0, y1):
    return max(x0 * x0, x1 * x1) + max(y0 * y0, y1 * y1)


@kernel(inline=True)
def _bin_box(vp, gx, gy, B, bx, by):
    l, r, b, t = vp[VP_L], vp[VP_R], vp[VP_B], vp[VP_T]
    cw = (r - l) / gx
    ch = (t - b) / gy
    x0 = l + bx * B * cw
    x1 = l + min((bx + 1) * B, gx) * cw
    y1 = t - by * B * ch
    y0 = t - min((by + 1) * B, gy) * ch
    return x0, x1, y0, y1


@kernel(inline=True)
def _quad_bin_range(qd, e, radius, dmax, corner2, vp, gx, gy, B):
    """(by0, by1, bx0, bx1): the screen bins the bounding box of quad e (grown by its half-width for
    every receiver, ``dmax``) touches; an empty range when the quad has no fragment."""
    if qd[e, 7] > 0.0:  # the rectangle: the hexagon's box (rect_reach)
        k = rect_k(qd, e, dmax)
        if k >= 0.0:
            ex, ey = k * qd[e, 8] + _EPS_IMG, k * qd[e, 9] + _EPS_IMG
            x0, x1 = min(qd[e, 0], qd[e, 2]) - ex, max(qd[e, 0], qd[e, 2]) + ex
            y0, y1 = min(qd[e, 1], qd[e, 3]) - ey, max(qd[e, 1], qd[e, 3]) + ey
            cx0, cx1, cy0, cy1 = _cell_range(x0, x1, y0, y1, vp, gx, gy)
            if cx0 <= cx1 and cy0 <= cy1:
                return cy0 // B, cy1 // B + 1, cx0 // B, cx1 // B + 1
    elif qd[e, 6] > 0.0:
        Rg = quad_half_width(qd, e, radius, dmax, corner2)
        if Rg > 0.0:
            if np.isfinite(Rg):
                x0 = min(qd[e, 0], qd[e, 2]) - Rg
                x1 = max(qd[e, 0], qd[e, 2]) + Rg
                y0 = min(qd[e, 1], qd[e, 3]) - Rg
                y1 = max(qd[e, 1], qd[e, 3]) + Rg
                cx0, cx1, cy0, cy1 = _cell_range(x0, x1, y0, y1, vp, gx, gy)
            else:
                cx0, cx1, cy0, cy1 = 0, gx - 1, 0, gy - 1
            if cx0 <= cx1 and cy0 <= cy1:
                return cy0 // B, cy1 // B + 1, cx0 // B, cx1 // B + 1
    return 0, 0, 0, 0


@kernel(nogil=True, nrt=False, noalias=True)
def _quad_bin_slots_slot(slot, qd, radius, dmax, corner2, vp, gx, gy, B, slots, nslot):
    """Per quad: the number of bins its bounding box touches (``_quad_bin_range``), the slots the
    test pass may fill. Run by ``run_slots``: slot ``slot`` of ``nslot`` takes one contiguous block
    of the quads."""
    E = qd.shape[0]
    for e in range(slot * E // nslot, (slot + 1) * E // nslot):
        by0, by1, bx0, bx1 = _quad_bin_range(qd, e, radius, dmax, corner2, vp, gx, gy, B)
        slots[e] = (by1 - by0) * (bx1 - bx0)


@kernel(nogil=True, nrt=False, noalias=True)
def _quad_bins_slot(
    slot, qd, radius, dmax, corner2, bin_maxd, per_bin, vp, gx, gy, B, nbx, bgeo, offs, out, counts, nslot
):
    """The screen bins quad e overlaps (refined per bin with ``per_bin``), in bin order, into its
    slots ``out[offs[e]:offs[e + 1]]`` (the rest of them -1) and their number into ``counts[e]``.
    One pass of the tests. ``bgeo``: per bin, :func:`_bin_geometry` (made once, not per quad). Run
    by ``run_slots``: slot ``slot`` of ``nslot`` takes one contiguous block of the quads."""
    cw, ch = (vp[VP_R] - vp[VP_L]) / gx, (vp[VP_T] - vp[VP_B]) / gy
    hb = 0.5 * B * np.sqrt(cw * cw + ch * ch) * (1.0 + 1e-12)  # a whole bin's half diagonal
    chb, shb = np.cos(hb), np.sin(hb) * (1.0 + 1e-12)
    E = qd.shape[0]
    for e in range(slot * E // nslot, (slot + 1) * E // nslot):
        n = 0
        k = offs[e]
        by0, by1, bx0, bx1 = _quad_bin_range(qd, e, radius, dmax, corner2, vp, gx, gy, B)
        Rg = quad_half_width(qd, e, radius, dmax, corner2)
        ux, uy, qcx, qcy, hl0, _hw = quad_axes(qd, e, 0.0)  # once per quad (only R varies per bin)
        rdm = reach_ratio(qd, e, radius)
        for by in range(by0, by1):
            if per_bin and not (qd[e, 7] > 0.0):
                # the sphere: skip a row of bins that no bin of it can hit. R grows with the
                # receiver distance and the stretch, so the row's largest distance and its box's
                # corner bound every bin's R; the quad with that R (and some slack) against the
                # row's box fails the separating axes if each bin's does (about 95% of the bins the
                # bounding range gives miss; this leaves the same list)
                dr = 0.0
                for bx in range(bx0, bx1):
                    dr = max(dr, bin_maxd[by * nbx + bx])
                if dr <= 0.0:
                    continue
                rx0, _rx, ry0, ry1 = _bin_box(vp, gx, gy, B, bx0, by)
                _rx, rx1, _ry0, _ry1 = _bin_box(vp, gx, gy, B, bx1 - 1, by)
                # every bin's R is at most this: R = A r (1/(d - r) - 1/D) (1 + slack) + 1e-12 with A
                # and D at most the row's, and at most 1e-12 where the middle factor is <= 0
                Rr = max(quad_half_width(qd, e, radius, dr, box_corner2(rx0, rx1, ry0, ry1)), 1e-12)
                if np.isfinite(Rr):
                    Rr = Rr * (1.0 + 1e-9) + 1e-12
                    pad = 1e-9 * (abs(rx0) + abs(rx1) + abs(ry0) + abs(ry1)) + 1e-12
                    if not axes_overlap_box(ux, uy, qcx, qcy, hl0 + Rr, Rr, rx0 - pad, rx1 + pad, ry0 - pad, ry1 + pad):
                        continue
            for bx in range(bx0, bx1):
                bi = by * nbx + bx
                if bin_maxd[bi] <= 0.0:
                    continue
                x0, x1, y0, y1 = bgeo[bi, 0], bgeo[bi, 1], bgeo[bi, 2], bgeo[bi, 3]
                if qd[e, 7] > 0.0:
                    kb = rect_k(qd, e, bin_maxd[bi] if per_bin else dmax)
                    hit = kb >= 0.0 and rect_reach(qd, e, x0, x1, y0, y1) <= kb
                else:
                    R = Rg
                    if per_bin:
                        R = quad_half_width(qd, e, radius, bin_maxd[bi], bgeo[bi, 4])
                    # the quad (segment grown by R) against the bin: separating axes
                    hit = R > 0.0 and (
                        not np.isfinite(R) or axes_overlap_box(ux, uy, qcx, qcy, hl0 + R, R, x0, x1, y0, y1)
                    )
                    if hit and np.isfinite(R):
                        # by angles (disk_cell_reach with the bin's centre and a whole bin's half
                        # diagonal, at least its own): the quad's stretch dropped
                        mx, my, mz = bgeo[bi, 5], bgeo[bi, 6], bgeo[bi, 7]
                        iDb = 1.0 / (bin_maxd[bi] if per_bin else dmax)
                        ang, entry = disk_cell_reach(mx, my, mz, chb, shb, qd[e, _QN:], rdm, radius, iDb)
                        hit = not (ang and entry < 0.0)
                if hit:
                    out[k + n] = bi
                    n += 1
        for i in range(k + n, offs[e + 1]):
            out[i] = -1
        counts[e] = n


@kernel
def _bin_geometry(vp, gx, gy, B, nbx, nby):
    """Per screen bin (nbx * nby, 8): its box (:func:`_bin_box`), the box's ``box_corner2`` and
    the unit direction through its centre (:func:`cell_direction`): what :func:`_quad_bins_slot`
    tests every quad against, the same values, computed once per bin instead of per (quad, bin)."""
    g = np.empty((nbx * nby, 8))
    for by in range(nby):
        for bx in range(nbx):
            bi = by * nbx + bx
            x0, x1, y0, y1 = _bin_box(vp, gx, gy, B, bx, by)
            g[bi, 0], g[bi, 1], g[bi, 2], g[bi, 3] = x0, x1, y0, y1
            g[bi, 4] = box_corner2(x0, x1, y0, y1)
            g[bi, 5], g[bi, 6], g[bi, 7] = cell_direction(0.5 * (x0 + x1), 0.5 * (y0 + y1), vp)
    return g


def window_corner2(vp) -> float:
    l, r, b, t = vp[VP_L : VP_T + 1]
    return float(max(l * l, r * r) + max(b * b, t * t))


def build_penumbra_quads(grid: SampleGrid, edges: Edges, light, light_radius: float) -> np.ndarray:
    """Step (c), setup: one light-view penumbra quad per silhouette edge (its image-plane segment,
    minimum distance to the light centre and stretch; the half-width follows from the receiver
    distance, :func:`quad_half_width`)."""
    shape, _b, _r, hu, hv, nrm_l, u, v = _light_params(light)
    qd = np.zeros((len(edges), _QCOLS))
    _quad_setup(
        edges.a, edges.b, grid.vp, grid.vp[VP_ORIGIN : VP_ORIGIN + 3].copy(), light_radius, shape, nrm_l, grid.dmax, qd
    )
    if shape == 0:
        # the rectangle's half-extents along the image axes (rect_reach); the view looks along its
        # normal (light_frame), so its corners lie at depth 0 (to rounding: u, v and the normal come
        # from the light's u x v)
        vr, vu, vf = (grid.vp[i : i + 3] for i in (VP_RIGHT, VP_UP, VP_FORWARD))
        qd[:, 8] = hu * abs(u @ vr) + hv * abs(v @ vr)
        qd[:, 9] = hu * abs(u @ vu) + hv * abs(v @ vu)
        assert hu * abs(u @ vf) + hv * abs(v @ vf) <= 1e-12 * (hu + hv)
    return qd


def bin_penumbra_quads(grid: SampleGrid, qd: np.ndarray, light_radius: float, per_bin: bool):
    """Step (c), sort-middle binning: each quad goes to the screen bins it overlaps; with
    ``per_bin`` (the first overdraw optimisation) its half-width is recomputed with each bin's
    maximum receiver distance and it is dropped from bins it then misses."""
    E = len(qd)
    counts = np.zeros(E, np.int64)
    args = (
        qd,
        light_radius,
        grid.dmax,
        window_corner2(grid.vp),
        grid.bin_maxd,
        per_bin,
        grid.vp,
        grid.gx,
        grid.gy,
        grid.bins,
        grid.nbx,
    )
    offs = np.zeros(E + 1, np.int64)
    nslot = numba.get_num_threads()
    run_slots(
        _quad_bin_slots_slot,
        nslot,
        qd,
        light_radius,
        grid.dmax,
        args[3],
        grid.vp,
        grid.gx,
        grid.gy,
        grid.bins,
        offs[1:],
        nslot,
    )
    np.cumsum(offs[1:], out=offs[1:])
    slots = np.empty(offs[-1], np.int64)
    bgeo = _bin_geometry(grid.vp, grid.gx, grid.gy, grid.bins, grid.nbx, grid.nby)
    run_slots(_quad_bins_slot, nslot, *args, bgeo, offs, slots, counts, nslot)
    return _pairs_by_bin(counts, slots[slots >= 0], grid.n_bins)


# ---------------------------------------------------------------------------------------------
# (d) final penumbra: exact signed edge integrals
# ---------------------------------------------------------------------------------------------
# The sample loop's helpers (to sample_edge_term) are inlined by LLVM and compiled without reference
# counting (nrt=False): with Numba's refcounting of the arrays they receive, LLVM-inlined they ran
# 1.2-1.3x slower and were inlined in Numba's IR instead, which cost compile time
# (softshadows/_jit.py, docs/results/cold-start.md).
@kernel(inline=True, nrt=False)
def segment_area(d, w0, w1):
    """Eq. 3: normalised area between a chord segment and the arc of the unit circle, inside the angle
    the segment [w0, w1] (positions along the chord line, at distance d >= 0 from the centre,
    already clipped to the circle) subtends at the centre: (theta - d (w1 - w0)) / (2 pi). theta,
    the paper's acos((d^2 + w0 w1) / sqrt((d^2 + w0^2)(d^2 + w1^2))), is taken as the angle between
    (w0, d) and (w1, d) by atan2 (same angle, no square root or division, and accurate near 0 where
    acos loses half the digits)."""
    theta = atan2_upper(d * (w1 - w0), d * d + w0 * w1)
    return (theta - d * (w1 - w0)) / (2.0 * np.pi)


@kernel(inline=True, nrt=False)
def _clip_poly(buf, src, n, a, b, c, dst):
    """Clip the polygon in rows (2 src, 2 src + 1) of ``buf`` (x, y; n >= 1 vertices) to
    a*x + b*y + c >= 0 into rows (2 dst, 2 dst + 1); returns the new count. Each vertex's value of
    the half-plane function is computed once."""
    sx, sy, dx, dy = 2 * src, 2 * src + 1, 2 * dst, 2 * dst + 1
    m = 0
    f0 = a * buf[sx, 0] + b * buf[sy, 0] + c
    fi = f0
    for i in range(n):
        j = i + 1
        if j < n:
            fj = a * buf[sx, j] + b * buf[sy, j] + c
        else:
            j = 0
            fj = f0
        if fi >= 0.0:
            buf[dx, m] = buf[sx, i]
            buf[dy, m] = buf[sy, i]
            m += 1
        if (fi >= 0.0) != (fj >= 0.0):
            t = fi / (fi - fj)
            buf[dx, m] = buf[sx, i] + t * (buf[sx, j] - buf[sx, i])
            buf[dy, m] = buf[sy, i] + t * (buf[sy, j] - buf[sy, i])
            m += 1
        fi = fj
    return m


#: per-sample row of the penumbra pass (:func:`sample_row`): p (3), w (3: unit, from p toward the
#: light's plane), L (distance to that plane), c - p (3)
_RP, _RW, _RL, _RC, _ROW = 0, 3, 6, 7, 10


@kernel(inline=True, nrt=False)
def sample_row(shape, center, nrm_l, sp, j, rows, k):
    """Row k of ``rows`` := everything the term evaluation reads for sorted sample j, contiguous
    (layout: _R*): p and the light frame (w: the facing disk's normal for the sphere, the
    rectangle's normal for the rectangle; L; c - p). Filled where a term needs it
    (``scalar_edge_terms``) into a per-worker scratch indexed from the bin's first sample, not for
    the whole frame at once."""
    rows[_RP, k] = sp[j, 0]
    rows[_RP + 1, k] = sp[j, 1]
    rows[_RP + 2, k] = sp[j, 2]
    cx, cy, cz = center[0] - sp[j, 0], center[1] - sp[j, 1], center[2] - sp[j, 2]
    rows[_RC, k] = cx
    rows[_RC + 1, k] = cy
    rows[_RC + 2, k] = cz
    if shape == 1:
        L = np.sqrt(cx * cx + cy * cy + cz * cz)
        rows[_RW, k] = cx / L
        rows[_RW + 1, k] = cy / L
        rows[_RW + 2, k] = cz / L
        rows[_RL, k] = L
    else:
        L = cx * nrm_l[0] + cy * nrm_l[1] + cz * nrm_l[2]
        s = 1.0 if L >= 0.0 else -1.0
        rows[_RW, k] = s * nrm_l[0]
        rows[_RW + 1, k] = s * nrm_l[1]
        rows[_RW + 2, k] = s * nrm_l[2]
        rows[_RL, k] = abs(L)


@kernel(inline=True, nrt=False)
def _side_sum(nx, ny, nz, p0, p1, p2, e, tv_start, tv):
    """Sum over the edge's counted triangles of the side of their third vertex relative to the plane
    through p and the edge (normal n): +1 / -1, 0 when in the plane."""
    wsum = 0.0
    for k in range(tv_start[e], tv_start[e + 1]):
        s = nx * (tv[k, 0] - p0) + ny * (tv[k, 1] - p1) + nz * (tv[k, 2] - p2)
        if s > 0.0:
            wsum += 1.0
        elif s < 0.0:
            wsum -= 1.0
    return wsum


@kernel(inline=True, nrt=False)
def _far_end(rax, ray, raz, rbx, rby, rbz, ha, hb):
    """The point of the edge in p's plane parallel to the light (where its projection runs to
    infinity), relative to p."""
    t0 = ha / (ha - hb)
    return rax + t0 * (rbx - rax), ray + t0 * (rby - ray), raz + t0 * (rbz - raz)


@kernel(inline=True, nrt=False)
def _disk_term(rw, j, radius, rax, ray, raz, rbx, rby, rbz, nx, ny, nz, nw, m2, nc):
    """V~ of the edge for the disk of radius r facing p (Eq. 3), given the plane (p, edge): its normal
    n, n . w and |n|^2 - (n . w)^2 (> 0), n . (c - p) (!= 0). The edge's line is the trace of the
    plane in the disk's plane; its endpoints are projected from p onto it."""
    wx, wy, wz, L = rw[_RW, j], rw[_RW + 1, j], rw[_RW + 2, j], rw[_RL, j]
    ha = rax * wx + ray * wy + raz * wz
    hb = rbx * wx + rby * wy + rbz * wz
    if ha <= 0.0 and hb <= 0.0:
        return 0.0  # the footprint radius at the edge is <= 0: the edge is behind p
    imr = 1.0 / (np.sqrt(m2) * radius)
    d = abs(nc) * imr
    if d >= 1.0:
        return 0.0
    # tangent T = w x n / m (in the disk plane, along the line); positions along it in units of r
    tx = wy * nz - wz * ny
    ty = wz * nx - wx * nz
    tz = wx * ny - wy * nx
    k = L * imr
    sa = 0.0
    sb = 0.0
    if ha > 0.0:
        sa = (rax * tx + ray * ty + raz * tz) * k / ha
    if hb > 0.0:
        sb = (rbx * tx + rby * ty + rbz * tz) * k / hb
    if ha <= 0.0 or hb <= 0.0:
        # one endpoint behind p: that end of the projected edge runs to infinity
        ox, oy, oz = _far_end(rax, ray, raz, rbx, rby, rbz, ha, hb)
        inf = np.inf if (ox * tx + oy * ty + oz * tz) >= 0.0 else -np.inf
        if ha <= 0.0:
            sa = inf
        else:
            sb = inf
    h = np.sqrt(1.0 - d * d)
    w0 = max(min(sa, sb), -h)
    w1 = min(max(sa, sb), h)
    if not (w1 > w0):
        return 0.0
    return segment_area(d, w0, w1)


@kernel(inline=True, nrt=False)
def _rect_term(rw, j, lu, lv, hu, hv, rax, ray, raz, rbx, rby, rbz, nu, nv, nc, buf):
    """V~ of the edge for the rectangle (2 hu x 2 hv, axes lu, lv): the exact area of the rectangle
    clipped to the far side of the edge's line (n . (c - p) + nu U + nv V against the sign of
    n . (c - p)) and to the angle the projected edge subtends at the centre (``_clip_poly``)."""
    wx, wy, wz, L = rw[_RW, j], rw[_RW + 1, j], rw[_RW + 2, j], rw[_RL, j]
    ha = rax * wx + ray * wy + raz * wz
    hb = rbx * wx + rby * wy + rbz * wz
    if ha <= 0.0 and hb <= 0.0:
        return 0.0
    so = 1.0 if nc > 0.0 else -1.0
    ux, uy, uz, vx, vy, vz = lu[0], lu[1], lu[2], lv[0], lv[1], lv[2]
    # directions (from the centre) of the projected endpoints
    cpx, cpy, cpz = -rw[_RC, j], -rw[_RC + 1, j], -rw[_RC + 2, j]  # p - c
    dax = day = dbx = dby = 0.0
    if ha > 0.0:
        k = L / ha
        dax = (cpx + rax * k) * ux + (cpy + ray * k) * uy + (cpz + raz * k) * uz
        day = (cpx + rax * k) * vx + (cpy + ray * k) * vy + (cpz + raz * k) * vz
    if hb > 0.0:
        k = L / hb
        dbx = (cpx + rbx * k) * ux + (cpy + rby * k) * uy + (cpz + rbz * k) * uz
        dby = (cpx + rbx * k) * vx + (cpy + rby * k) * vy + (cpz + rbz * k) * vz
    if ha <= 0.0 or hb <= 0.0:
        ox, oy, oz = _far_end(rax, ray, raz, rbx, rby, rbz, ha, hb)
        ix = ox * ux + oy * uy + oz * uz
        iy = ox * vx + oy * vy + oz * vz
        if ha <= 0.0:
            dax, day = ix, iy
        else:
            dbx, dby = ix, iy
    if ha > 0.0 and hb > 0.0:
        # both projected endpoints beyond one side of the rectangle: so is the whole region beyond
        # the edge inside the angle (their hull plus the rays from the centre through them)
        mu, mv = hu * (1.0 + _SLACK), hv * (1.0 + _SLACK)
        if (dax > mu and dbx > mu) or (dax < -mu and dbx < -mu) or (day > mv and dby > mv) or (day < -mv and dby < -mv):
            return 0.0
    cr = dax * dby - day * dbx
    if cr == 0.0:
        return 0.0
    sw = 1.0 if cr > 0.0 else -1.0
    buf[0, 0], buf[1, 0] = -hu, -hv
    buf[0, 1], buf[1, 1] = hu, -hv
    buf[0, 2], buf[1, 2] = hu, hv
    buf[0, 3], buf[1, 3] = -hu, hv
    n = 4
    # beyond the line: n.(c - p) + nu U + nv V has the sign opposite to n.(c - p)
    n = _clip_poly(buf, 0, n, -so * nu, -so * nv, -so * nc, 1)
    if n < 3:
        return 0.0
    # inside the angle: sw * cross(da, X) >= 0 and sw * cross(X, db) >= 0
    n = _clip_poly(buf, 1, n, -sw * day, sw * dax, 0.0, 0)
    if n < 3:
        return 0.0
    n = _clip_poly(buf, 0, n, sw * dby, -sw * dbx, 0.0, 1)
    if n < 3:
        return 0.0
    area = 0.0
    for i in range(n):
        k = i + 1 if i + 1 < n else 0
        area += buf[2, i] * buf[3, k] - buf[2, k] * buf[3, i]
    return abs(area) * 0.5 / (4.0 * hu * hv)


@kernel(inline=True, nrt=False)
def sample_edge_term(shape, rw, j, lu, lv, radius, hu, hv, e, ea, eb, tv_start, tv, buf):
    """Signed penumbral occlusion of edge e at sample j (row ``rw[j]``): sum over the edge's counted
    triangles of (+V~ when the light centre is outside the triangle's side of the edge, -V~
    inside), V~ the normalised area of the light's projection (from p, onto its plane) inside the
    angle the edge subtends at the centre and beyond the edge (Fig. 4): ``_disk_term`` (Eq. 3) or
    ``_rect_term``. Edge parts at or behind p's plane parallel to the light project to infinity.

    Cheap exits first, each giving the exact 0 the full term would: for fold candidates (two or
    more counted triangles) the triangles usually cancel as seen from p (``_side_sum``); for
    silhouettes first whether the edge's line misses the light's footprint."""
    p0, p1, p2 = rw[_RP, j], rw[_RP + 1, j], rw[_RP + 2, j]
    rax, ray, raz = ea[e, 0] - p0, ea[e, 1] - p1, ea[e, 2] - p2
    rbx, rby, rbz = eb[e, 0] - p0, eb[e, 1] - p1, eb[e, 2] - p2
    nx = ray * rbz - raz * rby
    ny = raz * rbx - rax * rbz
    nz = rax * rby - ray * rbx
    many = tv_start[e + 1] - tv_start[e] >= 2
    wsum = 0.0
    if many:
        wsum = _side_sum(nx, ny, nz, p0, p1, p2, e, tv_start, tv)
        if wsum == 0.0:
            return 0.0
    nc = nx * rw[_RC, j] + ny * rw[_RC + 1, j] + nz * rw[_RC + 2, j]  # n . (c - p)
    if nc == 0.0:
        return 0.0
    if shape == 1:
        nw = nx * rw[_RW, j] + ny * rw[_RW + 1, j] + nz * rw[_RW + 2, j]
        m2 = nx * nx + ny * ny + nz * nz - nw * nw
        if m2 <= 0.0 or nc * nc >= m2 * (radius * radius):
            return 0.0  # the line misses the disk (d >= 1)
        if not many:
            wsum = _side_sum(nx, ny, nz, p0, p1, p2, e, tv_start, tv)
            if wsum == 0.0:
                return 0.0  # the counted triangles at this edge cancel as seen from p
        vt = _disk_term(rw, j, radius, rax, ray, raz, rbx, rby, rbz, nx, ny, nz, nw, m2, nc)
    else:
        nu = nx * lu[0] + ny * lu[1] + nz * lu[2]
        nv = nx * lv[0] + ny * lv[1] + nz * lv[2]
        if abs(nc) >= abs(nu) * hu + abs(nv) * hv:
            return 0.0  # the line misses the rectangle (its support in direction (nu, nv))
        if not many:
            wsum = _side_sum(nx, ny, nz, p0, p1, p2, e, tv_start, tv)
            if wsum == 0.0:
                return 0.0
        vt = _rect_term(rw, j, lu, lv, hu, hv, rax, ray, raz, rbx, rby, rbz, nu, nv, nc, buf)
    if vt == 0.0:
        return 0.0
    so = 1.0 if nc > 0.0 else -1.0
    return -so * wsum * vt


@kernel(inline=True)
def _sign(s):
    """+1.0 / -1.0 / 0.0 by the sign of s (0.0 for NaN), as a select."""
    return np.float64(s > 0.0) - np.float64(s < 0.0)


@kernel(inline=True)
def drop_cancelling(cp, m, center, e, ea, eb, tv_start, tv, sel, cand, flags):
    """For an edge with two counted triangles (a fold candidate): drop the samples ``cand[:m]``
    (positions ``cp[:, :m]``) where the two cancel as seen from p or p lies in the plane through
    the light centre and the edge (the first two exits of ``disk_edge_terms`` and of
    ``rect_edge_terms``, the same expressions, so the same bits: exact zeros), compacting ``cp``
    and ``cand`` in place; returns how many are left. A cheap first pass (two cross products' worth,
    branch-free): on ``bunny`` 39% of the disk's candidates are such zeros, which the vectorized
    terms would otherwise evaluate in full (1.15x on the sphere's penumbra pass, 1.18x on the
    rectangle's). The survivors' indices are packed by ``compact_indices`` from the int8 ``flags``
    (``sel`` and ``flags`` with 8 entries of slack): a scalar loop of ``sel[n] = i; n += keep``
    waited on n at every candidate."""
    ax, ay, az, bx, by, bz = ea[e, 0], ea[e, 1], ea[e, 2], eb[e, 0], eb[e, 1], eb[e, 2]
    k1 = tv_start[e]
    v1x, v1y, v1z, v2x, v2y, v2z = tv[k1, 0], tv[k1, 1], tv[k1, 2], tv[k1 + 1, 0], tv[k1 + 1, 1], tv[k1 + 1, 2]
    c0, c1, c2 = center[0], center[1], center[2]
    for i in range(m):
        p0, p1, p2 = cp[0, i], cp[1, i], cp[2, i]
        cx, cy, cz = c0 - p0, c1 - p1, c2 - p2
        rax, ray, raz = ax - p0, ay - p1, az - p2
        rbx, rby, rbz = bx - p0, by - p1, bz - p2
        nx = ray * rbz - raz * rby
        ny = raz * rbx - rax * rbz
        nz = rax * rby - ray * rbx
        w2 = _sign(nx * (v2x - p0) + ny * (v2y - p1) + nz * (v2z - p2))
        wsum = 0.0 + _sign(nx * (v1x - p0) + ny * (v1y - p1) + nz * (v1z - p2))
        wsum = wsum + w2
        nc = nx * cx + ny * cy + nz * cz
        flags[i] = np.int8(wsum != 0.0) & np.int8(nc != 0.0)
    n = compact_indices(flags, m, 0, sel, 0)
    for t in range(n):
        i = sel[t]  # >= t
        cand[t] = cand[i]
        cp[0, t], cp[1, t], cp[2, t] = cp[0, i], cp[1, i], cp[2, i]
    return n


#: rows of :func:`disk_edge_terms`' scratch between its passes: w = (c - p) / L, n, L, n.(c - p),
#: m2, ha, hb, the sign factor, the first exits' flag; then d, w0, w1 (over the first rows)
_DW, _DN, _DL, _DNC, _DM2, _DHA, _DHB, _DF, _DOK = 0, 3, 6, 7, 8, 9, 10, 11, 12
_DD, _DW0, _DW1 = 0, 1, 2


@kernel(inline=True)
def disk_edge_terms(cp, m, center, radius, e, ea, eb, tv_start, tv, sc, out):
    """``sample_edge_term`` for the disk (``shape == 1``) at the m candidate samples whose positions
    are ``cp[:, :m]`` (copied contiguous), for one edge with one or two counted triangles, into
    ``out[:m]``: the same arithmetic in the same order (``sample_row``'s c - p, L and w included),
    every early exit made a select, so that the loops run branch-free on contiguous data and
    vectorize. Bit for bit the values of the scalar path (an early exit gives an exact 0). In three
    passes through the scratch ``sc`` (rows ``_D*``): the term is one long chain of dependent
    square roots and divisions, which kept a single loop waiting on their latencies (its body too
    long for the core to overlap two iterations); the exits and the clipped segment first, then
    Eq. 3 at every candidate, the exits' values discarded by a select. The survivors are not
    compacted first: ``drop_cancelling`` has already dropped most of the early exits, and
    compacting the rest cost more than their areas (of `bunny`'s 602k candidates that reach it
    568k survive; the penumbra pass 0.95-0.98 of its time before, 2026-12-04)."""
    rr = radius * radius
    ax, ay, az, bx, by, bz = ea[e, 0], ea[e, 1], ea[e, 2], eb[e, 0], eb[e, 1], eb[e, 2]
    k1 = tv_start[e]
    two = tv_start[e + 1] - k1 == 2
    k2 = k1 + 1 if two else k1
    v1x, v1y, v1z, v2x, v2y, v2z = tv[k1, 0], tv[k1, 1], tv[k1, 2], tv[k2, 0], tv[k2, 1], tv[k2, 2]
    c0, c1, c2 = center[0], center[1], center[2]
    for i in range(m):
        p0, p1, p2 = cp[0, i], cp[1, i], cp[2, i]
        # sample_row
        cx, cy, cz = c0 - p0, c1 - p1, c2 - p2
        L = math.sqrt(cx * cx + cy * cy + cz * cz)
        wx, wy, wz = cx / L, cy / L, cz / L
        # sample_edge_term
        rax, ray, raz = ax - p0, ay - p1, az - p2
        rbx, rby, rbz = bx - p0, by - p1, bz - p2
        nx = ray * rbz - raz * rby
        ny = raz * rbx - rax * rbz
        nz = rax * rby - ray * rbx
        w2 = _sign(nx * (v2x - p0) + ny * (v2y - p1) + nz * (v2z - p2))
        wsum = 0.0 + _sign(nx * (v1x - p0) + ny * (v1y - p1) + nz * (v1z - p2))  # _side_sum
        wsum = wsum + w2 if two else wsum
        nc = nx * cx + ny * cy + nz * cz
        nw = nx * wx + ny * wy + nz * wz
        m2 = nx * nx + ny * ny + nz * nz - nw * nw
        ok = (wsum != 0.0) & (nc != 0.0) & ~(m2 <= 0.0) & ~(nc * nc >= m2 * rr)
        # _disk_term
        ha = rax * wx + ray * wy + raz * wz
        hb = rbx * wx + rby * wy + rbz * wz
        ok &= ~((ha <= 0.0) & (hb <= 0.0))
        so = 1.0 if nc > 0.0 else -1.0
        sc[_DW, i], sc[_DW + 1, i], sc[_DW + 2, i] = wx, wy, wz
        sc[_DN, i], sc[_DN + 1, i], sc[_DN + 2, i] = nx, ny, nz
        sc[_DL, i], sc[_DNC, i], sc[_DM2, i], sc[_DHA, i], sc[_DHB, i] = L, nc, m2, ha, hb
        sc[_DF, i] = -so * wsum
        sc[_DOK, i] = 1.0 if ok else 0.0
    for i in range(m):
        p0, p1, p2 = cp[0, i], cp[1, i], cp[2, i]
        wx, wy, wz = sc[_DW, i], sc[_DW + 1, i], sc[_DW + 2, i]
        nx, ny, nz = sc[_DN, i], sc[_DN + 1, i], sc[_DN + 2, i]
        L, nc, m2, ha, hb = sc[_DL, i], sc[_DNC, i], sc[_DM2, i], sc[_DHA, i], sc[_DHB, i]
        ok = sc[_DOK, i] != 0.0
        rax, ray, raz = ax - p0, ay - p1, az - p2
        rbx, rby, rbz = bx - p0, by - p1, bz - p2
        imr = 1.0 / (math.sqrt(m2) * radius)
        d = abs(nc) * imr
        ok &= ~(d >= 1.0)
        tx = wy * nz - wz * ny
        ty = wz * nx - wx * nz
        tz = wx * ny - wy * nx
        k = L * imr
        sa = (rax * tx + ray * ty + raz * tz) * k / ha
        sb = (rbx * tx + rby * ty + rbz * tz) * k / hb
        sa = sa if ha > 0.0 else 0.0
        sb = sb if hb > 0.0 else 0.0
        ox, oy, oz = _far_end(rax, ray, raz, rbx, rby, rbz, ha, hb)
        inf = np.inf if (ox * tx + oy * ty + oz * tz) >= 0.0 else -np.inf
        sa = inf if ha <= 0.0 else sa
        sb = inf if (hb <= 0.0) & ~(ha <= 0.0) else sb
        h = math.sqrt(1.0 - d * d)
        w0 = max(min(sa, sb), -h)
        w1 = min(max(sa, sb), h)
        ok &= w1 > w0
        sc[_DD, i], sc[_DW0, i], sc[_DW1, i] = d, w0, w1
        sc[_DOK, i] = 1.0 if ok else 0.0
    for i in range(m):  # (an exit's segment may be NaN: the select discards it)
        a = sc[_DF, i] * segment_area(sc[_DD, i], sc[_DW0, i], sc[_DW1, i])
        out[i] = a if sc[_DOK, i] != 0.0 else 0.0


#: rows of :func:`rect_edge_terms`' scratch: the projected edge as P + t V, 0 <= t <= tmax (P, V, tmax;
#: rows 5-6 free), the term's sign and weight (0: an exact zero)
_RP0, _RV, _RT, _RF, _RSC = 0, 2, 4, 7, 8
#: rows of the edge terms' scratch (:func:`disk_edge_terms`' are more)
_TERM_ROWS = max(_RSC, _DOK + 1)


@kernel(nrt=False)
def rect_edge_terms(cp, m, center, nrm_l, lu, lv, hu, hv, e, ea, eb, tv_start, tv, sc, out):
    """``sample_edge_term`` for the rectangle (``shape == 0``) at the m candidate samples whose
    positions are ``cp[:, :m]``, for one edge with one or two counted triangles, into ``out[:m]``
    (an early exit gives an exact 0): the twin of
    :func:`disk_edge_terms` (``sample_row``'s rectangle part, every early exit a select, branch-free
    on contiguous data: it vectorizes). ``_rect_term``'s Sutherland-Hodgman clipping (data-dependent
    vertex counts) is replaced by the same region's area as the sector of the rectangle between
    the projected edge's ends clipped to it, less the triangle they make with the centre
    (:func:`softshadows.analytic.rect_beyond_segment_area`): not the same bits as the scalar path,
    the same values to rounding (tests/test_irregular.py). In two passes: every exit test and the
    projected edge (a segment, or a ray from its end in front of p) into the scratch ``sc`` (rows
    ``_R*``), then the area at every candidate, an exit's discarded by a select. The survivors are not compacted first: ``drop_cancelling`` has
    already dropped nearly every early exit (of `bunny`'s 1.10M candidates 568k reach this
    function and 539k survive its exits), and compacting cost more than the few areas it spared
    (the penumbra pass 0.91-0.93 of its time before, 2026-12-04). A function of its own, like
    ``scalar_edge_terms`` (inlined into ``_penumbra_kernel`` it added 4.5 s to that kernel's compile
    time), without reference counting (it allocates nothing)."""
    ax, ay, az, bx, by, bz = ea[e, 0], ea[e, 1], ea[e, 2], eb[e, 0], eb[e, 1], eb[e, 2]
    k1 = tv_start[e]
    two = tv_start[e + 1] - k1 == 2
    k2 = k1 + 1 if two else k1
    v1x, v1y, v1z, v2x, v2y, v2z = tv[k1, 0], tv[k1, 1], tv[k1, 2], tv[k2, 0], tv[k2, 1], tv[k2, 2]
    c0, c1, c2 = center[0], center[1], center[2]
    l0, l1, l2 = nrm_l[0], nrm_l[1], nrm_l[2]
    ux, uy, uz, vx, vy, vz = lu[0], lu[1], lu[2], lv[0], lv[1], lv[2]
    mu, mv = hu * (1.0 + _SLACK), hv * (1.0 + _SLACK)
    norm = 1.0 / (4.0 * hu * hv)
    for i in range(m):
        p0, p1, p2 = cp[0, i], cp[1, i], cp[2, i]
        # sample_row
        cx, cy, cz = c0 - p0, c1 - p1, c2 - p2
        Ls = cx * l0 + cy * l1 + cz * l2
        sl = 1.0 if Ls >= 0.0 else -1.0
        wx, wy, wz, L = sl * l0, sl * l1, sl * l2, abs(Ls)
        # sample_edge_term
        rax, ray, raz = ax - p0, ay - p1, az - p2
        rbx, rby, rbz = bx - p0, by - p1, bz - p2
        nx = ray * rbz - raz * rby
        ny = raz * rbx - rax * rbz
        nz = rax * rby - ray * rbx
        w2 = _sign(nx * (v2x - p0) + ny * (v2y - p1) + nz * (v2z - p2))
        wsum = 0.0 + _sign(nx * (v1x - p0) + ny * (v1y - p1) + nz * (v1z - p2))  # _side_sum
        wsum = wsum + w2 if two else wsum
        nc = nx * cx + ny * cy + nz * cz
        nu = nx * ux + ny * uy + nz * uz
        nv = nx * vx + ny * vy + nz * vz
        ok = (wsum != 0.0) & (nc != 0.0) & ~(abs(nc) >= abs(nu) * hu + abs(nv) * hv)
        # _rect_term: the projected endpoints' directions from the centre (the far end for one behind p)
        ha = rax * wx + ray * wy + raz * wz
        hb = rbx * wx + rby * wy + rbz * wz
        pa, pb = ha > 0.0, hb > 0.0
        ok &= pa | pb
        k = L / ha
        dax = (rax * k - cx) * ux + (ray * k - cy) * uy + (raz * k - cz) * uz
        day = (rax * k - cx) * vx + (ray * k - cy) * vy + (raz * k - cz) * vz
        k = L / hb
        dbx = (rbx * k - cx) * ux + (rby * k - cy) * uy + (rbz * k - cz) * uz
        dby = (rbx * k - cx) * vx + (rby * k - cy) * vy + (rbz * k - cz) * vz
        ox, oy, oz = _far_end(rax, ray, raz, rbx, rby, rbz, ha, hb)
        ix = ox * ux + oy * uy + oz * uz
        iy = ox * vx + oy * vy + oz * vz
        dax = dax if pa else ix
        day = day if pa else iy
        dbx = ix if pa & ~pb else dbx
        dby = iy if pa & ~pb else dby
        # both projected endpoints beyond one side of the rectangle
        out_u = ((dax > mu) & (dbx > mu)) | ((dax < -mu) & (dbx < -mu))
        out_v = ((day > mv) & (dby > mv)) | ((day < -mv) & (dby < -mv))
        ok &= ~(pa & pb & (out_u | out_v))
        cr = dax * dby - day * dbx
        ok &= cr != 0.0
        so = 1.0 if nc > 0.0 else -1.0
        # the projected edge as P + t V, 0 <= t <= tmax: the segment from A to B, or with one end
        # behind p the ray from the other along the far end's direction (on the edge's line)
        # (as products with 0 / 1 weights, exact for finite ends: an end behind p is the far end's
        # finite direction; one projected from a hair in front of p's plane may overflow, and its
        # NaN then gives a zero area, rect_beyond_segment_area's comparisons failing. As selects on
        # pa, LLVM made the loop 4x slower)
        seg = pa & pb
        wa = 1.0 if pa else 0.0
        ws = 1.0 if seg else 0.0
        px, py = dax * wa + dbx * (1.0 - wa), day * wa + dby * (1.0 - wa)
        qx, qy = dbx * wa + dax * (1.0 - wa), dby * wa + day * (1.0 - wa)  # the other end
        sc[_RP0, i] = px
        sc[_RP0 + 1, i] = py
        sc[_RV, i] = (qx - px) * ws + qx * (1.0 - ws)
        sc[_RV + 1, i] = (qy - py) * ws + qy * (1.0 - ws)
        sc[_RT, i] = 1.0 if seg else np.inf
        f = -so * wsum
        sc[_RF, i] = f if ok else 0.0
    for i in range(m):
        # the rectangle beyond the projected edge's line, inside the angle it subtends at the centre
        area = rect_beyond_segment_area(
            hu, hv, sc[_RP0, i], sc[_RP0 + 1, i], sc[_RV, i], sc[_RV + 1, i], sc[_RT, i]
        )  # fmt: skip
        f = sc[_RF, i]
        out[i] = 0.0 if f == 0.0 else f * (area * norm)  # (an exit's area may be NaN)


@kernel(nrt=False)
def scalar_edge_terms(
    shape, center, nrm_l, spos, rw, jb, cand, m, lu, lv, radius, hu, hv, e, ea, eb, tv_start, tv, buf, out
):
    """``sample_edge_term`` at the samples ``cand[:m]`` into ``out[:m]``: the path of the rectangle
    and of edges with more than two counted triangles. A function of its own, called once per (edge,
    bin), not inlined into ``_penumbra_kernel``: its helpers, inlined here, stay out of the parallel
    kernel's body, whose compile time grows faster than its size (about a third less for
    ``_penumbra_kernel``). Without reference counting (``nrt=False``): with it, Numba increfs and
    decrefs the arrays its inlined helpers receive at every sample (atomic operations), and the
    rectangle's pass ran 1.9x slower."""
    for i in range(m):
        sample_row(shape, center, nrm_l, spos, cand[i], rw, cand[i] - jb)  # made here, where needed
        out[i] = sample_edge_term(shape, rw, cand[i] - jb, lu, lv, radius, hu, hv, e, ea, eb, tv_start, tv, buf)


@kernel(inline=True, nrt=False)
def cancels_in_box(e, ea, eb, tv_start, tv, box, c):
    """True when edge e's counted triangles cancel at every point of 3D box ``c``: the sign of a
    sample's term for triangle (a, b, v) is -sign(((b - a) x (v - a)) . (p - a)); when every such
    sign is constant on the box and they sum to zero, every sample in it gets an exact 0."""
    if tv_start[e + 1] - tv_start[e] < 2:
        return False
    ux, uy, uz = eb[e, 0] - ea[e, 0], eb[e, 1] - ea[e, 1], eb[e, 2] - ea[e, 2]
    mx = 0.5 * (box[c, 0] + box[c, 3]) - ea[e, 0]
    my = 0.5 * (box[c, 1] + box[c, 4]) - ea[e, 1]
    mz = 0.5 * (box[c, 2] + box[c, 5]) - ea[e, 2]
    hx, hy, hz = 0.5 * (box[c, 3] - box[c, 0]), 0.5 * (box[c, 4] - box[c, 1]), 0.5 * (box[c, 5] - box[c, 2])
    total = 0
    for k in range(tv_start[e], tv_start[e + 1]):
        vx, vy, vz = tv[k, 0] - ea[e, 0], tv[k, 1] - ea[e, 1], tv[k, 2] - ea[e, 2]
        nx = uy * vz - uz * vy
        ny = uz * vx - ux * vz
        nz = ux * vy - uy * vx
        val = nx * mx + ny * my + nz * mz
        ext = (abs(nx) * hx + abs(ny) * hy + abs(nz) * hz) * (1.0 + _SLACK) + 1e-300
        if abs(val) <= ext:
            return False
        total += 1 if val > 0.0 else -1
    return total == 0


@kernel(nogil=True)
def _penumbra_kernel(
    _worker,
    wc2,
    col_box,
    g_start,
    gx,
    gy,
    B,
    nbx,
    S,
    sb,
    dmax,
    bin_maxd,
    vp,
    shape,
    center,
    nrm_l,
    spos,
    sdist,
    six,
    siy,
    u,
    v,
    radius,
    hu,
    hv,
    qd,
    ea,
    eb,
    tv_start,
    tv,
    bin_start,
    bin_items,
    per_bin,
    wedge,
    count_only,
    pen,
    frags,
    tests,
    hits,
    evals,
    bin_order,
    counter,
    max_col,
    max_bin,
    umbra,
    order,
    dest,
    vout,
    compose,
):
    """One worker of the penumbra pass (:func:`accumulate_penumbrae`), run by ``run_slots``, one per
    thread: takes the next bin of ``bin_order`` (``next_item``) until none is left. With
    ``compose``, a bin's samples are final once its quads are done (no other bin writes them; their
    ``umbra`` counts are complete): step (e), :func:`compose_range`, writes their V into ``vout`` at
    ``dest`` right then, while they are in cache, instead of a pass of its own after this one."""
    l, r, b, t = vp[VP_L], vp[VP_R], vp[VP_B], vp[VP_T]
    cw = (r - l) / gx
    ch = (t - b) / gy
    hd = 0.5 * np.sqrt(cw * cw + ch * ch) * (1.0 + 1e-12)  # a cell's half diagonal (rounded up)
    chd, shd = np.cos(hd), np.sin(hd) * (1.0 + 1e-12)  # (disk_cell_reach) the angle it bounds
    buf = np.zeros((4, 8))  # scratch, once per worker
    cand = np.empty(max_bin + 8, np.int64)  # (compact_indices writes 8 at a time)
    cval = np.empty(max_bin)
    ms = row_stride(max_bin)  # (a row length that keeps a column's rows in different cache sets)
    cp = np.empty((3, ms))  # the candidates' positions, contiguous
    rsc = np.empty((_TERM_ROWS, ms))  # the edge terms' scratch
    sel = np.empty(max_bin + 8, np.int64)  # (compact_indices writes 8 at a time)
    dflags = np.empty(max_bin + 8, np.int8)  # drop_cancelling's flags
    keep = np.empty(max_col, np.int8)
    rw = np.empty((_ROW, ms))  # the current bin's sample rows (one row per field) and 1 / distance
    sinv = np.empty(max_bin)
    sdir = np.empty((3, ms))  # the bin's samples' unit directions from the light centre (sphere)
    mdir = np.empty((3, B * B))  # the current bin's cells' directions (disk_cell_reach)
    capp = np.empty(B * B)  # per (edge, bin): each cell's disk_cell_reach (disk_cells_reach)
    cent = np.empty(B * B)
    c0, c1, c2 = center[0], center[1], center[2]
    while True:
        q = next_item(counter)
        if q >= bin_order.shape[0]:
            break
        bi = bin_order[q]
        by = bi // nbx
        bx = bi % nbx
        jb = g_start[bi * B * B * S]  # the bin's first sample: rw and sinv are indexed from it
        je = g_start[(bi + 1) * B * B * S]
        has_items = bin_start[bi] < bin_start[bi + 1]  # (without: a bin only composed)
        if not count_only and has_items:
            if shape == 0:  # the rectangle's bound: 1 / view depth (rect_reach)
                f0, f1, f2 = vp[VP_FORWARD], vp[VP_FORWARD + 1], vp[VP_FORWARD + 2]
                for j in range(jb, je):
                    dz = (spos[j, 0] - vp[VP_ORIGIN]) * f0 + (spos[j, 1] - vp[VP_ORIGIN + 1]) * f1
                    sinv[j - jb] = 1.0 / (dz + (spos[j, 2] - vp[VP_ORIGIN + 2]) * f2)
            else:
                for j in range(jb, je):  # (rows: where needed, scalar_edge_terms)
                    iD = 1.0 / sdist[j]
                    sinv[j - jb] = iD
                    # the unit direction from the light centre (disk_reach), one row per axis
                    sdir[0, j - jb] = (spos[j, 0] - c0) * iD
                    sdir[1, j - jb] = (spos[j, 1] - c1) * iD
                    sdir[2, j - jb] = (spos[j, 2] - c2) * iD
        bx0, bx1, by0, by1 = _bin_box(vp, gx, gy, B, bx, by)
        if shape == 1 and has_items:  # the directions through the bin's cells' centres (disk_cell_reach)
            for cy in range(by * B, min(by * B + B, gy)):
                for cx in range(bx * B, min(bx * B + B, gx)):
                    lc = (cy - by * B) * B + cx - bx * B
                    y1 = t - cy * ch
                    mdir[0, lc], mdir[1, lc], mdir[2, lc] = cell_direction(
                        l + cx * cw + 0.5 * cw, y1 - ch + 0.5 * ch, vp
                    )
        bc2 = box_corner2(bx0, bx1, by0, by1)
        nf = 0
        nt = 0
        nh = 0
        nev = 0
        for kk in range(bin_start[bi], bin_start[bi + 1]):
            e = bin_items[kk]
            R = (
                quad_half_width(qd, e, radius, bin_maxd[bi], bc2)
                if per_bin
                else quad_half_width(qd, e, radius, dmax, wc2)
            )
            # per edge: its image-plane segment, stretch and the inverse of (dmin - r) of the
            # per-sample bound below
            qax, qay, qbx, qby, dmin, q5 = qd[e, 0], qd[e, 1], qd[e, 2], qd[e, 3], qd[e, 4], qd[e, 5]
            dr = dmin - radius if dmin > radius else 0.0
            inv_dr = 1.0 / dr if dr > 0.0 else 0.0
            rect = shape == 0  # the exact hexagon of rect_reach instead of the quad
            izm = qd[e, 7]
            kq = rect_k(qd, e, bin_maxd[bi] if per_bin else dmax)
            if (kq < 0.0) if rect else (R <= 0.0):
                continue  # no fragment
            every = not (rect or np.isfinite(R))  # the light's sphere reaches the edge: every cell
            ux, uy, qcx, qcy, hl, hw = quad_axes(qd, e, 1.0 if (every or rect) else R)
            sdx, sdy = qbx - qax, qby - qay
            s_uu = sdx * sdx + sdy * sdy
            s_iuu = 1.0 / s_uu if s_uu > 0.0 else 0.0
            # the wedge entry's per-cell division, hoisted: 1 / (stretch r (1 + slack))
            wk = 1.0 / ((1.0 + max(q5, bc2)) * radius) / (1.0 + _SLACK)
            # the rectangle's per-sample test (rect_reach at a point, k of the sample's depth)
            rhx, rhy = qd[e, 8], qd[e, 9]
            rmx, rmy = 0.5 * (qax + qbx), 0.5 * (qay + qby)
            rex, rey = 0.5 * abs(sdx) + _EPS_IMG, 0.5 * abs(sdy) + _EPS_IMG
            rhn, ren = rhx * abs(sdy) + rhy * abs(sdx), _EPS_IMG * (abs(sdx) + abs(sdy))
            # the sphere's per-sample test (disk_reach): r / dmin with its margins, the edge's arc
            rdm = reach_ratio(qd, e, radius) if not rect else 0.0
            iDb = 1.0 / (bin_maxd[bi] if per_bin else dmax)  # (disk_cell_reach) the farthest receivers
            arc = qd[e, _QN:]
            if shape == 1 and not every:  # the bin's cells' test against this edge, all at once
                disk_cells_reach(mdir, B * B, chd, shd, arc, rdm, radius, iDb, capp, cent)
            # the bin's cells that can overlap the quad's bounding box (one cell of margin for
            # rounding: every cell outside is one ``axes_overlap_box`` rejects on the box axes)
            cx_lo, cx_hi, cy_lo, cy_hi = bx * B, min(bx * B + B, gx), by * B, min(by * B + B, gy)
            if not every:
                ex = hl * abs(ux) + hw * abs(uy)
                ey = hl * abs(uy) + hw * abs(ux)
                if rect:  # (rect_reach) the hexagon's box
                    ex, ey = 0.5 * abs(sdx) + kq * rhx + _EPS_IMG, 0.5 * abs(sdy) + kq * rhy + _EPS_IMG
                cx_lo = int(max(np.floor((qcx - ex - l) / cw) - 1.0, cx_lo))
                cx_hi = int(min(np.floor((qcx + ex - l) / cw) + 2.0, cx_hi))
                cy_lo = int(max(np.floor((t - qcy - ey) / ch) - 1.0, cy_lo))
                cy_hi = int(min(np.floor((t - qcy + ey) / ch) + 2.0, cy_hi))
            m = 0  # candidates of this edge in this bin: cand[:m]
            for cy in range(cy_lo, cy_hi):
                y1 = t - cy * ch
                y0 = y1 - ch
                for cx in range(cx_lo, cx_hi):
                    x0 = l + cx * cw
                    x1 = x0 + cw
                    ci = bi * B * B + (cy - by * B) * B + cx - bx * B  # the column (cy % B = cy - by B)
                    col = ci * S
                    if g_start[col] == g_start[col + S]:
                        continue
                    kc = 0.0
                    dent = -1.0  # the sphere's wedge entry by angles (disk_cell_reach), if it applies
                    if rect:
                        kc = rect_reach(qd, e, x0, x1, y0, y1)
                        if kc > kq:
                            continue
                    elif not every:
                        lc = (cy - by * B) * B + cx - bx * B
                        ang, dent = capp[lc] != 0.0, cent[lc]
                        if ang:
                            if dent < 0.0:
                                continue
                        elif not axes_overlap_box(ux, uy, qcx, qcy, hl, hw, x0, x1, y0, y1):
                            continue
                    if cancels_in_box(e, ea, eb, tv_start, tv, col_box, ci):
                        continue
                    nf += 1
                    s0 = 0
                    if dent >= 0.0:
                        if wedge:
                            s0 = slice_of(dent * (1.0 - _SLACK), sb)
                    elif rect:
                        # the wedge enters the column where k = 1/z_min - 1/z reaches kc: at depth (so
                        # at distance) 1 / (1/z_min - kc) or beyond
                        if wedge and kc > 0.0:
                            inv = izm - kc / (1.0 + _SLACK)
                            if inv <= 0.0:
                                continue
                            s0 = slice_of((1.0 / inv) * (1.0 - _SLACK), sb)
                    elif wedge and dmin > radius:
                        # the wedge enters this column at the distance where its angular radius
                        # reaches the column: r (1/(dmin - r) - 1/D) * stretch >= dist(cell, edge)
                        # dc: the distance from the segment to the cell's centre minus its half
                        # diagonal (>= 0), a lower bound of the distance to the cell; no division
                        mx, my = x0 + 0.5 * cw, y0 + 0.5 * ch
                        ta = ((mx - qax) * sdx + (my - qay) * sdy) * s_iuu
                        ta = min(max(ta, 0.0), 1.0)
                        ox, oy = qax + ta * sdx - mx, qay + ta * sdy - my
                        dc = max(np.sqrt(ox * ox + oy * oy) - hd, 0.0)
                        inv = inv_dr - dc * wk
                        if inv <= 0.0:
                            continue
                        s0 = slice_of((1.0 / inv) * (1.0 - _SLACK), sb)
                    j0, j1 = g_start[col + s0], g_start[col + S]
                    nt += j1 - j0
                    if count_only:
                        continue
                    # the same bound at each sample itself: its image-plane distance to the
                    # edge's image against the angular radius at its own distance (stretch
                    # from its own off-axis angle and the edge's endpoints); branch-free, the
                    # survivors' indices compacted into ``cand``
                    if rect:
                        # rect_reach at each sample (a point) with its own k: same form, branch-free
                        for i in range(j1 - j0):
                            j = np.uint64(j0 + i)
                            k = (izm - sinv[np.uint64(j0 - jb + i)]) * (1.0 + _SLACK)
                            ddx, ddy = six[j] - rmx, siy[j] - rmy
                            kx = abs(ddx) <= rex + k * rhx
                            ky = abs(ddy) <= rey + k * rhy
                            kn = abs(sdx * ddy - sdy * ddx) <= ren + k * rhn
                            keep[np.uint64(i)] = np.int8(kx) & np.int8(ky) & np.int8(kn)
                        m = compact_indices(keep, j1 - j0, j0, cand, m)
                    elif dr > 0.0:
                        # disk_reach at each sample, branch-free; unsigned indices (no
                        # negative-index wrap-around code) and selects: the loop vectorizes
                        for i in range(j1 - j0):
                            k = np.uint64(j0 - jb + i)
                            keep[np.uint64(i)] = disk_reach(
                                sdir[0, k], sdir[1, k], sdir[2, k], sinv[k], radius, rdm, arc
                            )
                        m = compact_indices(keep, j1 - j0, j0, cand, m)
                    else:
                        for j in range(j0, j1):
                            cand[m] = j
                            m += 1
            # the edge's candidates in this bin, every cell's together (longer vector loops)
            nev += m
            nt_e = tv_start[e + 1] - tv_start[e]
            if nt_e == 1 or nt_e == 2:
                for i in range(m):  # the candidates' positions, contiguous: the terms' loop vectorizes
                    jc = np.uint64(cand[i])  # (>= 0: unsigned, no wrap-around code)
                    cp[0, i], cp[1, i], cp[2, i] = spos[jc, 0], spos[jc, 1], spos[jc, 2]
                if nt_e == 2:  # (both lights: the same first two exits as either terms' loop)
                    m = drop_cancelling(cp, np.int64(m), center, e, ea, eb, tv_start, tv, sel, cand, dflags)
                if shape == 1:
                    disk_edge_terms(cp, np.int64(m), center, radius, e, ea, eb, tv_start, tv, rsc, cval)
                else:
                    rect_edge_terms(cp, np.int64(m), center, nrm_l, u, v, hu, hv, e, ea, eb, tv_start, tv, rsc, cval)
            else:
                scalar_edge_terms(
                    shape,
                    center,
                    nrm_l,
                    spos,
                    rw,
                    jb,
                    cand,
                    np.int64(m),  # never Literal[int](0): one specialisation
                    u,
                    v,
                    radius,
                    hu,
                    hv,
                    e,
                    ea,
                    eb,
                    tv_start,
                    tv,
                    buf,
                    cval,
                )
            for i in range(m):  # branch-free (about half the terms are zero): adding a zero, of
                # either sign, leaves a sum that is never -0.0 the same bits
                c = cval[i]
                nh += c != 0.0
                pen[np.uint64(cand[i])] += c
        frags[bi] = nf
        tests[bi] = nt
        hits[bi] = nh
        evals[bi] = nev
        if compose:
            compose_range(jb, je, order, dest, umbra, pen, vout)


def _light_params(light):
    if light.shape == "sphere":
        z = np.zeros(3)
        return 1, float(light.radius), float(light.radius), 0.0, 0.0, z, z, z
    u = light.u / np.linalg.norm(light.u)
    v = light.v - np.dot(light.v, u) * u
    v = v / np.linalg.norm(v)
    hu = 0.5 * float(np.linalg.norm(light.u))
    hv = 0.5 * float(abs(np.dot(light.v, v)))
    return 0, float(np.hypot(hu, hv)), 0.0, hu, hv, np.asarray(light.normal, float), u, v


def accumulate_penumbrae(
    grid: SampleGrid, edges: Edges, qd, bins, light, per_bin: bool, wedge: bool, count_only: bool = False
):
    """Step (d): for every bin, every quad in its list, every cell of the bin the quad covers (a
    fragment) and every sample of that cell column at or beyond the wedge's entry slice (the second
    overdraw optimisation, ``wedge``): add the edge's signed exact occlusion (Eq. 3 for the disk,
    the clipped rectangle for the rectangle light). One thread per bin at a time (no two threads write
    the same sample). -> (pen, stats)."""
    return PenumbraPass(grid, edges, qd, bins, light, per_bin, wedge, count_only).run()


class PenumbraPass:
    """:func:`accumulate_penumbrae` in two steps: made (its inputs and outputs set up, on the
    calling thread: :func:`irregular_visibility` does it while the slot threads count umbrae), then
    ``run()`` -> (pen, stats). With ``compose``, the pass also does step (e) bin by bin
    (:func:`compose_range`; every bin with samples is visited): ``run_composed(umbra, n_all,
    pixels)`` -> (V, pen, stats), V as :func:`compose_visibility` gives it."""

    def __init__(
        self, grid: SampleGrid, edges: Edges, qd, bins, light, per_bin, wedge, count_only=False, compose=False
    ):
        shape, bound_r, radius, hu, hv, nrm_l, u, v = _light_params(light)
        n = len(grid.order)
        self.pen = np.zeros(n)
        self.compose = bool(compose) and not count_only
        self.order = grid.order
        nb = grid.n_bins
        self.frags, self.tests, self.hits = np.zeros(nb, np.int64), np.zeros(nb, np.int64), np.zeros(nb, np.int64)
        self.evals = np.zeros(nb, np.int64)
        rad = radius if shape == 1 else bound_r
        self.args = (
            window_corner2(grid.vp),
            grid.col_box,
            grid.start,
            grid.gx,
            grid.gy,
            grid.bins,
            grid.nbx,
            grid.slices,
            grid.sbound,
            grid.dmax,
            grid.bin_maxd,
            grid.vp,
            shape,
            np.asarray(light.center, float),
            nrm_l,
            grid.pos,
            grid.dist,
            grid.ix,
            grid.iy,
            u,
            v,
            rad,
            hu,
            hv,
            qd,
            edges.a,
            edges.b,
            edges.tv_start,
            edges.tv,
            bins[0],
            bins[1],
            per_bin,
            wedge,
            count_only,
            self.pen,
            self.frags,
            self.tests,
            self.hits,
            self.evals,
            bins_by_work(bins[0], grid.start, grid.bins * grid.bins * grid.slices, also_empty=self.compose),
            work_counter(),
            grid.max_column,
            grid.max_bin,
        )

    def run(self):
        """The pass, one worker per thread (``run_slots``): (pen, stats)."""
        if self.compose:
            raise ValueError("a composing PenumbraPass runs with run_composed()")
        return self._run(np.empty(0, np.int32), np.empty(0, np.int64), np.empty(0, np.float32))

    def run_composed(self, umbra, n_all: int, pixels=None):
        """The pass and step (e) in it: (V (n_all,) float32, pen, stats), V = 1 - (umbra + pen)
        clamped at ``pixels`` (each grid input sample's place in V; default: its index), 1
        elsewhere."""
        if not self.compose:
            raise ValueError("this PenumbraPass was made without compose")
        v = np.ones(n_all, np.float32)
        dest = np.arange(n_all, dtype=np.int64) if pixels is None else np.asarray(pixels, np.int64)
        pen, st = self._run(np.asarray(umbra, np.int32), dest, v)  # (count_umbrae's int32: no copy)
        return v, pen, st

    def _run(self, umbra, dest, vout):
        run_slots(_penumbra_kernel, numba.get_num_threads(), *self.args, umbra, self.order, dest, vout, self.compose)
        return self.pen, {
            "fragments": int(self.frags.sum()),
            "sample_tests": int(self.tests.sum()),
            "evaluated_terms": int(self.evals.sum()),
            "nonzero_terms": int(self.hits.sum()),
        }


# ---------------------------------------------------------------------------------------------
# composition
# ---------------------------------------------------------------------------------------------
@kernel(inline=True)
def compose_range(j0, j1, order, dest, umbra, pen, out):
    """Eq. 4 with C = 0 for the grid's samples j0..j1 (sorted order): V = 1 - (umbra + pen),
    clamped to [0, 1], written to ``out[dest[order[j]]]`` (``dest`` one-to-one: no two samples
    write one place)."""
    for j in range(np.uint64(j0), np.uint64(j1)):  # unsigned: see _sample_keys_slot
        x = 1.0 - (umbra[j] + pen[j])
        out[np.uint64(dest[np.uint64(order[j])])] = min(max(x, 0.0), 1.0)  # (indices >= 0: unsigned)


@kernel(nogil=True, nrt=False, noalias=True)
def _compose_slot(slot, order, dest, umbra, pen, out, nslot):
    """:func:`compose_range` of the whole grid (``out`` already 1 everywhere). Run by
    ``run_slots``: slot ``slot`` of ``nslot`` takes one contiguous block of the grid's samples."""
    m = order.shape[0]
    compose_range(slot * m // nslot, (slot + 1) * m // nslot, order, dest, umbra, pen, out)


def compose_visibility(grid: SampleGrid, umbra, pen, n_all: int, pixels=None) -> np.ndarray:
    """Eq. 4 with C = 0: V = 1 - (umbral count + summed signed penumbral occlusion), clamped to
    [0, 1]; samples outside the grid (behind the light's view) are lit. V of the n_all input
    samples, or with ``pixels`` (each input sample's flat pixel index) an image of n_all pixels,
    1 where no sample lies (``FrameContext.scatter``'s, without the per-sample array)."""
    out = np.ones(n_all, np.float32)
    run_threads(_compose_slot, grid.order, np.arange(n_all) if pixels is None else pixels, umbra, pen, out)
    return out


#: points per block of ``_error_bound_samples``
_EB_BLOCK = 256


@kernel(nogil=True, noalias=True)
def _error_bound_samples_slot(
    slot, verts, faces, tri_img, bary_img, pos_img, nrm_img, eye, idx, eps, lc, frame, out, bound, part, counter, nslot
):
    """Ground truth's ray origins (:func:`ground_truth.hit_point`, float64): p + (BOUND_SAFETY x its
    error bound + eps) n, n the geometric normal turned toward the eye; gathers from the G-buffer
    (its triangle, barycentrics, and position and normal for the side toward the ``eye``, turned as
    ``gather_points`` turns them, the same arithmetic: no per-sample arrays of its own).
    By blocks of points: the triangles' vertices and the points' inputs gathered into contiguous
    scratch first (a point on the previous point's triangle stores the corners it holds in
    registers: neighbouring pixels mostly share a triangle, and the chain of dependent loads to a
    triangle's vertices was a third of the kernel's time), then ``hit_point_at`` in a loop without
    gathers or branches (it vectorizes), its outputs stored contiguous and copied to the rows of
    ``out`` last: the same arithmetic, the same bits as ``hit_point`` point by point. Also each block's row of ``part`` (``_extent_slot``'s:
    the block's box and its smallest and largest distance to the light centre ``lc``), for
    :func:`fold_extent`, and with a ``frame`` (rows right, up, forward: the rectangle's, which does
    not depend on the samples) its columns 8-14 (``_window_of_slot``'s window of the samples with
    z > 0, and their smallest z), for :func:`fold_window`: the grid's extent and window without
    further passes over the samples. Run by ``run_slots``: each slot takes the
    next block (``next_item``) until none is left (its scratch made once): with fixed halves, one
    thread finished ~0.3 ms after the other on `bunny`."""
    n = idx.shape[0]
    nblk = (n + _EB_BLOCK - 1) // _EB_BLOCK
    g = np.empty((17, row_stride(_EB_BLOCK)))  # inputs (14 rows), then the result (3)
    ex, ey, ez = eye[0], eye[1], eye[2]
    while True:
        blk = next_item(counter)
        if blk >= nblk:
            break
        k0 = blk * _EB_BLOCK
        m = min(n, k0 + _EB_BLOCK) - k0
        tp = -1
        # the current triangle's corners, kept in registers: copied from the previous column they
        # made a chain of stores and loads through memory from one sample to the next
        a0 = a1 = a2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
        for i in range(m):
            # unsigned indices (pixels, faces and vertices are >= 0): no negative-index wrap-around
            # code at each of the loop's gathers (the pass 0.94-0.95x, 2026-12-05)
            q = np.uint64(idx[np.uint64(k0 + i)])
            t = tri_img[q]
            if t != tp:  # (a neighbouring pixel mostly shares its triangle: its corners again)
                # the chain triangle -> face -> vertices, each a dependent load (Embree's float32
                # vertex coordinates, embree_coord)
                tu = np.uint64(t)
                va, vb, vc = np.uint64(faces[tu, 0]), np.uint64(faces[tu, 1]), np.uint64(faces[tu, 2])
                a0, a1, a2 = embree_coord(verts[va, 0]), embree_coord(verts[va, 1]), embree_coord(verts[va, 2])
                b0, b1, b2 = embree_coord(verts[vb, 0]), embree_coord(verts[vb, 1]), embree_coord(verts[vb, 2])
                c0, c1, c2 = embree_coord(verts[vc, 0]), embree_coord(verts[vc, 1]), embree_coord(verts[vc, 2])
            tp = t
            g[0, i], g[1, i], g[2, i] = a0, a1, a2
            g[3, i], g[4, i], g[5, i] = b0, b1, b2
            g[6, i], g[7, i], g[8, i] = c0, c1, c2
            g[9, i] = np.float64(bary_img[q, 0])
            g[10, i] = np.float64(bary_img[q, 1])
            # the normal turned toward the eye (gather_points' expression, float32 images)
            px, py, pz = pos_img[q, 0], pos_img[q, 1], pos_img[q, 2]
            nx, ny, nz = nrm_img[q, 0], nrm_img[q, 1], nrm_img[q, 2]
            if nx * (ex - px) + ny * (ey - py) + nz * (ez - pz) < 0.0:
                nx, ny, nz = -nx, -ny, -nz
            g[11, i], g[12, i], g[13, i] = nx, ny, nz
        # the block's rows of ``bound`` and ``out`` as views indexed from 0: LLVM then knows every
        # index is >= 0 (k0 + i might be negative: its wrap-around select made the store a scatter,
        # a fifth of the kernel's samples in perf)
        bb, ob = bound[k0 : k0 + m], out[k0 : k0 + m]
        for i in range(m):
            px, py, pz, nx, ny, nz, ep, ee, _g = hit_point_at(
                g[0, i], g[1, i], g[2, i], g[3, i], g[4, i], g[5, i], g[6, i], g[7, i], g[8, i],
                g[9, i], g[10, i], g[11, i], g[12, i], g[13, i],
            )  # fmt: skip
            b = BOUND_SAFETY * (ep + ee)
            bb[i] = b
            off = b + eps
            g[14, i] = px + off * nx
            g[15, i] = py + off * ny
            g[16, i] = pz + off * nz
        # the block's row of part: _extent_slot's reduction, fused with the copy (written once
        # more rather than shared: a shared helper reading the rows back from ``out`` made this
        # pass ~7% slower on one thread)
        lo0 = lo1 = lo2 = d0 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        d1 = 0.0
        for i in range(m):
            x, y, z = g[14, i], g[15, i], g[16, i]
            ob[i, 0], ob[i, 1], ob[i, 2] = x, y, z
            lo0, lo1, lo2 = min(lo0, x), min(lo1, y), min(lo2, z)
            hi0, hi1, hi2 = max(hi0, x), max(hi1, y), max(hi2, z)
            dx, dy, dz = x - lc[0], y - lc[1], z - lc[2]
            d2 = dx * dx + dy * dy + dz * dz
            d0, d1 = min(d0, d2), max(d1, d2)
        part[blk, 0], part[blk, 1], part[blk, 2], part[blk, 3] = lo0, lo1, lo2, np.sqrt(d0)
        part[blk, 4], part[blk, 5], part[blk, 6], part[blk, 7] = hi0, hi1, hi2, np.sqrt(d1)
        if frame.shape[0] == 3:
            _block_window(g, m, lc, frame, part, blk)


@kernel(inline=True)
def _block_window(g, m, o, fr, part, blk):
    """Columns 8-14 of ``part[blk]``: ``_window_of_slot``'s (x0, x1, y0, y1, z0, z1) of the block's
    samples (rows 14-16 of ``g``) in the view (o; fr[0], fr[1], fr[2]) with z > 0 (the same
    expressions), and the smallest z of all of them. The projections first, into rows 0-2 (the
    inputs', free by now), every sample's, without a branch: that loop vectorizes (its divisions
    among the kernel's scalar ones took 18% of it; the error-bound pass 0.93-0.96x with the loops
    split), then the reductions."""
    x0, x1, y0, y1, z0, z1, za = np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf, np.inf
    o0, o1, o2 = o[0], o[1], o[2]
    r0, r1, r2, u0, u1, u2 = fr[0, 0], fr[0, 1], fr[0, 2], fr[1, 0], fr[1, 1], fr[1, 2]
    f0, f1, f2 = fr[2, 0], fr[2, 1], fr[2, 2]
    for i in range(m):  # (a sample with z <= 0: its x, y are discarded below)
        dx, dy, dz = g[14, i] - o0, g[15, i] - o1, g[16, i] - o2
        z = dx * f0 + dy * f1 + dz * f2
        g[0, i] = (dx * r0 + dy * r1 + dz * r2) / z
        g[1, i] = (dx * u0 + dy * u1 + dz * u2) / z
        g[2, i] = z
    for i in range(m):
        z = g[2, i]
        za = min(za, z)
        if z > 0.0:
            x, y = g[0, i], g[1, i]
            x0, x1, y0, y1 = min(x0, x), max(x1, x), min(y0, y), max(y1, y)
            z0, z1 = min(z0, z), max(z1, z)
    part[blk, 8], part[blk, 9], part[blk, 10], part[blk, 11] = x0, x1, y0, y1
    part[blk, 12], part[blk, 13], part[blk, 14] = z0, z1, za


@kernel
def _fold_window(part, w):
    """``w`` (7,) := columns 8-14 of the rows of ``part`` (:func:`_block_window`) folded in order."""
    w[0], w[1], w[2], w[3], w[4], w[5], w[6] = np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf, np.inf
    for q in range(part.shape[0]):
        w[0], w[1] = min(w[0], part[q, 8]), max(w[1], part[q, 9])
        w[2], w[3] = min(w[2], part[q, 10]), max(w[3], part[q, 11])
        w[4], w[5] = min(w[4], part[q, 12]), max(w[5], part[q, 13])
        w[6] = min(w[6], part[q, 14])


@dataclass
class SampleBounds:
    """What :func:`error_bound_samples` knows of its samples for the grid (:func:`build_sample_grid`):
    ``extent`` (:func:`_extent`'s lo, hi, d0, d1) and, for the rectangle, ``window``
    (:func:`fit_grid_view`'s)."""

    extent: tuple
    window: tuple | None = None
    toward: np.ndarray | None = None  # (the sphere) the point the window's frame looks toward


#: the statistic ``origin_bound_median`` is the median of every ``_BOUND_MEDIAN_STRIDE``-th sample's
#: error bound: the median of all of them (one partition of `bunny`'s 227k bounds) cost 0.5-0.8 ms
#: of a ~37 ms frame (``benchmarks/frame_ab.py``: rect 38.1 -> 37.6 ms subsampled, 36.7 -> 35.9 ms
#: without the statistic), of every 16th 0.15-0.17 ms of a ~22 ms frame (NumPy's partition takes
#: ~10 ns an element here), of every 64th (3.5k bounds) 0.03 ms; for a statistic that shows the
#: bound's scale
_BOUND_MEDIAN_STRIDE = 64


def bound_median(bound: np.ndarray) -> float:
    """The statistic ``origin_bound_median``: the median of every ``_BOUND_MEDIAN_STRIDE``-th
    entry of ``bound`` (in sample order: the same whatever the thread count); 0 when empty."""
    return median_in_place(bound[::_BOUND_MEDIAN_STRIDE].copy()) if len(bound) else 0.0


def median_in_place(x: np.ndarray) -> float:
    """``np.median(x)`` for x without NaNs, x partitioned in place around its middle once (0.3 ms
    for `bunny`'s 227k bounds against 0.7 ms: ``np.median`` partitions around both middles and the
    maximum); for an even count the lower middle is the largest value below the upper one."""
    k = len(x) // 2
    x.partition(k)
    return float(x[k]) if len(x) % 2 else float(0.5 * (x[:k].max() + x[k]))


def error_bound_samples(flat, eye, idx, eye_pos, eps, light, toward=None):
    """(samples (K,3), bound (K,), bounds): the samples at ground truth's ray origins plus ``eps``
    along the normal (the same points as ``hit_points`` + ``offset_points`` of ``gather_points``'
    normals, without their temporaries) at the G-buffer ``eye``'s flat pixels ``idx``, seen from
    ``eye_pos`` (the camera), and their :class:`SampleBounds` for ``light``'s grid, the same bits
    as :func:`_extent` and :func:`_window_of` would give: the window in the rectangle's frame, or
    for the sphere in the frame toward ``toward`` (none without it)."""
    K = len(idx)
    out = np.empty((K, 3))
    bound = np.empty(K)
    part = np.empty(((K + _EB_BLOCK - 1) // _EB_BLOCK, 15))
    tri, bary = eye.tri_id.ravel(), eye.bary.reshape(-1, 2)
    pos, nrm = eye.position.reshape(-1, 3), eye.normal.reshape(-1, 3)
    c = np.asarray(light.center, np.float64)
    framed = light.shape == "rect" or toward is not None
    frame = np.array(light_frame(light, toward=toward), np.float64) if framed else np.zeros((0, 3))
    run_threads(
        _error_bound_samples_slot, flat.vertices, flat.faces, tri, bary, pos, nrm, np.asarray(eye_pos, np.float64),
        np.asarray(idx, np.int64), eps, c, frame, out, bound, part, work_counter(),
    )  # fmt: skip
    window = None
    if framed and K:
        w = np.empty(7)
        _fold_window(part, w)
        window = tuple(float(x) for x in w)
    tw = None if toward is None or light.shape == "rect" else np.asarray(toward, np.float64)
    return out, bound, SampleBounds(fold_extent(part, K), window, tw)


def offset_points(pts, nrm, eps, bound=None):
    """Samples moved along their normals by ``eps`` (scene units) plus, per sample, ``bound``."""
    if bound is None and eps == 0.0:
        return np.ascontiguousarray(pts, dtype=np.float64)
    off = eps if bound is None else bound + eps
    return np.ascontiguousarray(pts + (off[:, None] if np.ndim(off) else off) * nrm, dtype=np.float64)


#: the method's defaults (``Irregular.params`` and :func:`irregular_visibility`'s keywords): light-view
#: grid cells per side, grid cells per screen-bin side, depth slices
GRID, BINS, SLICES = 96, 8, 8


def irregular_visibility(
    scene,
    pts,
    nrm,
    *,
    grid=GRID,
    bins=BINS,
    slices=SLICES,
    per_bin=True,
    wedge=True,
    silhouettes="adjacency",
    folds=True,
    offset=0.0,
    origin_bound=None,
    overdraw_stats=False,
    timer=None,
    raw=False,
    pixels=None,
    n_pixels=0,
    bounds=None,
):
    """V at eye samples (K,) float32 and stats; the steps of Figure 2 in order. Each sample is
    moved along its normal by ``origin_bound`` (per sample, scene units: the ray-origin error bound
    of :func:`ground_truth.hit_points`; none when None) plus ``offset`` x the scene diagonal. With
    ``raw``, also (umbral count, penumbral sum) per input sample (NaN for samples outside the
    grid). With ``pixels`` (the samples' flat pixel indices), V is an image of ``n_pixels`` pixels
    instead (1 where no sample lies). ``bounds``: the samples' :class:`SampleBounds`
    (:func:`error_bound_samples`), used when nothing moves them (no ``origin_bound``, no ``offset``)."""
    import contextlib

    def phase(name):
        return timer.phase(name) if timer is not None else contextlib.nullcontext()

    light = scene.light
    flat = scene.flat
    lo, hi = scene.bounds()
    eps = offset * float(np.linalg.norm(hi - lo))
    stats = {}
    with phase("construction"):
        p = offset_points(pts, nrm, eps, origin_bound)
        moved = origin_bound is not None or eps != 0.0
        g = build_sample_grid(light, p, grid, bins, slices, None if moved else bounds)
    with phase("hard_kernel"):
        fc = facing_and_counted(flat, light.center)
        occ, counted = fc[0], fc[2]
        umbrae = start_umbrae(g, flat.vertices, np.ascontiguousarray(occ), counted, light.center)
    with phase("soft_kernel"):
        # while the slot threads count umbrae, the calling thread alone selects the silhouettes,
        # builds and bins their quads and sets up step (d), then joins the umbra count
        try:
            with calling_thread_only():
                box = receivers_box(g.col_box) if len(g.order) else None
                bound_r = _light_params(light)[1]
                edges, st_s = select_silhouette_edges(flat, light.center, silhouettes, folds, box, bound_r, fc)
                qd = build_penumbra_quads(g, edges, light, bound_r)
                bl = bin_penumbra_quads(g, qd, bound_r, per_bin)
                penumbrae = PenumbraPass(g, edges, qd, bl, light, per_bin, wedge, compose=True)
        finally:  # (if the work above raised: nothing is raised while the slot threads still count)
            umbra, st_u = umbrae.finish()
        # steps (d) and (e): accumulate_penumbrae, composing each bin's V (compose_visibility's)
        # as soon as its quads are done
        v, pen, st_p = penumbrae.run_composed(umbra, len(pts) if pixels is None else n_pixels, pixels)
    stats.update(
        samples=int(len(pts)),
        grid_samples=int(len(g.order)),
        grid=f"{g.gx}x{g.gy}x{g.slices}",
        nonempty_cells=g.nonempty_cells,
        mean_samples_per_cell=len(g.order) / g.nonempty_cells if g.nonempty_cells else 0.0,
        max_samples_per_cell=g.max_cell,
        quads=int(len(edges)),
        quad_bin_pairs=int(len(bl[1])),
        quad_fragments=st_p["fragments"],
        penumbra_sample_tests=st_p["sample_tests"],
        penumbra_evaluated_terms=st_p["evaluated_terms"],
        penumbra_nonzero_terms=st_p["nonzero_terms"],
        eps=eps,
        origin_bound_median=bound_median(origin_bound) if origin_bound is not None else 0.0,
        **st_u,
        **st_s,
    )
    if overdraw_stats:
        for pb in (False, True):
            blx = bin_penumbra_quads(g, qd, bound_r, pb)
            for wd in (False, True):
                _p, st = accumulate_penumbrae(g, edges, qd, blx, light, pb, wd, count_only=True)
                tag = f"bins_{'on' if pb else 'off'}_wedge_{'on' if wd else 'off'}"
                stats[f"overdraw_{tag}"] = {
                    "quad_bin_pairs": int(len(blx[1])),
                    **{k: st[k] for k in ("fragments", "sample_tests")},
                }
    if raw:
        um = np.full(len(pts), np.nan)
        pe = np.full(len(pts), np.nan)
        um[g.order] = umbra
        pe[g.order] = pen
        return v, stats, um, pe
    return v, stats


@register
class Irregular(Method):
    name = "irregular"
    light_view = True  # renders/projects the occluders from the light (limits: softshadows.limits)
    light_shapes = ("rect", "sphere")
    summary = "soft irregular shadow mapping: exact umbra count + exact per-edge penumbra at every eye sample"
    paper = "Johnson et al. 2009"
    params = (
        Param("grid", GRID, "light-view grid cells per side (image plane)", min=1, max=4096),
        Param("slices", SLICES, "depth slices of the perspective grid", min=1, max=1024),
        Param(
            "bins",
            BINS,
            "grid cells per screen-bin side (the unit of parallel work and of quad refinement)",
            min=1,
            max=4096,
        ),
        Param("per_bin", True, "overdraw optimisation 1: refine each quad's width with each bin's max receiver depth"),
        Param("wedge", True, "overdraw optimisation 2: per fragment, test only samples beyond the wedge's entry slice"),
        Param(
            "silhouettes",
            "adjacency",
            "silhouette edges from mesh adjacency, or every edge of every counted triangle",
            choices=("adjacency", "all-edges"),
        ),
        Param(
            "folds",
            True,
            "with adjacency, also edges that fold as seen from some receiver (off: silhouettes from the light "
            "centre only, as the paper)",
        ),
        Param(
            "origin",
            "error-bound",
            "sample positions: ground-truth's ray origins (hit point recomputed in float64, offset by its float "
            "error bound), or the G-buffer's points (then only `offset` moves them)",
            choices=("error-bound", "gbuffer"),
        ),
        Param(
            "offset",
            0.0,
            "extra sample offset along the normal, x scene diagonal (as ground-truth's; 1e-4 with origin=gbuffer "
            "is the rule before ground-truth's error bounds)",
            min=0.0,
        ),
        Param("overdraw_stats", False, "also count fragments/tests with each optimisation off (extra passes)"),
    )

    #: what `softshadows pareto` sweeps (Method.sweep): V is exact whatever the grid; its size
    #: trades construction against the tests per cell
    sweep: ClassVar = {"grid": [64, 96, 128, 256]}

    def run(self, ctx, grid, slices, bins, per_bin, wedge, silhouettes, folds, origin, offset, overdraw_stats):
        extra, bounds = {}, None
        if origin == "error-bound":
            # the samples straight from the G-buffer: no gathered positions and normals
            idx, nrm = ctx.pixels(), None
            with ctx.timer.phase("construction"):
                lo, hi = ctx.scene.bounds()
                eps = offset * float(np.linalg.norm(hi - lo))
                eye_pos = np.asarray(ctx.scene.camera.eye, np.float64)
                # the sphere's grid frame toward the scene's box centre, known before the samples:
                # their window in it comes with them (no pass of its own, fit_grid_view)
                pts, bound, bounds = error_bound_samples(
                    ctx.flat, ctx.eye, idx, eye_pos, eps, ctx.scene.light, toward=(lo + hi) / 2
                )
            # the samples are in place: no further offset
            offset = 0.0
            extra = {"eps": eps, "origin_bound_median": bound_median(bound)}
        else:
            pts, nrm, idx = ctx.points()
        v, stats = irregular_visibility(
            ctx.scene,
            pts,
            nrm,
            grid=grid,
            bins=bins,
            slices=slices,
            per_bin=per_bin,
            wedge=wedge,
            silhouettes=silhouettes,
            folds=folds,
            offset=offset,
            overdraw_stats=overdraw_stats,
            timer=ctx.timer,
            pixels=idx,
            n_pixels=ctx.eye.mask.size,
            bounds=bounds,
        )
        stats.update(extra)
        return MethodOutput(v.reshape(ctx.eye.mask.shape), stats)
