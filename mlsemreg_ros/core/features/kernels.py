# Copyright 2026 The mlsemreg_ros Authors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""
Compiled (numba) kernels: availability, on-disk cache, voxel grid, warm-up.

The compiled kernels replace the NumPy passes of voxelization and FPFH with
single loops over the points or point pairs; the NumPy code stays the
reference and the fallback. They are used when numba imports and the
environment variable ``MLSEMREG_KERNELS`` is not ``numpy`` (read at every
call, so a test or a benchmark can switch).

Every kernel is ``@njit(cache=True, nogil=True)``: compiled once, stored on
disk, and run without the GIL (FPFH runs beside Local-SS on a second thread).
Cache directory: ``NUMBA_CACHE_DIR`` if set; else numba's default (``__pycache__``
beside this file) when this package's folder is writable; else
``$XDG_CACHE_HOME/mlsemreg_ros/numba`` (default ``~/.cache/mlsemreg_ros/numba``),
else ``<tmp>/mlsemreg_ros-numba-<uid>``. It is chosen before numba is imported;
when numba was imported earlier with no cache directory of its own, the choice is
written into ``numba.config.CACHE_DIR`` (it then applies to the whole process).

Start-up: :func:`mlsemreg_ros.core.features.warm_up.warm_up` compiles (first run: seconds) or
loads from the cache (~0.15 s) every kernel. :func:`keep_freed_memory` (opt-in,
process-wide) stops glibc from returning freed temporaries to the system at every frame.
"""

from __future__ import annotations

from collections.abc import Callable
import ctypes
import ctypes.util
import os
from pathlib import Path
import sys
import tempfile
from typing import Any, NamedTuple

import numpy as np

ENV_SWITCH = 'MLSEMREG_KERNELS'
"""Environment variable: ``numpy`` disables the compiled kernels."""


def cache_directory() -> str | None:
    """Directory for numba's cache, or None for numba's default (``__pycache__`` here)."""
    if os.environ.get('NUMBA_CACHE_DIR'):
        return os.environ['NUMBA_CACHE_DIR']
    here = Path(__file__).resolve().parent
    if os.access(here, os.W_OK):
        return None
    base = Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache')
    uid = os.getuid() if hasattr(os, 'getuid') else 0
    for candidate in (
        base / 'mlsemreg_ros' / 'numba',
        Path(tempfile.gettempdir()) / f'mlsemreg_ros-numba-{uid}',
    ):
        try:
            candidate.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(candidate, os.W_OK):
            return str(candidate)
    return None


def _configure_cache() -> None:
    chosen = cache_directory()
    if chosen is None or os.environ.get('NUMBA_CACHE_DIR'):
        return
    if 'numba' in sys.modules:  # too late for the environment variable
        config = sys.modules['numba'].config
        if not getattr(config, 'CACHE_DIR', ''):
            config.CACHE_DIR = chosen
    else:
        os.environ['NUMBA_CACHE_DIR'] = chosen


try:
    _configure_cache()
    from numba import njit as _njit

    AVAILABLE = True
except ImportError:  # the NumPy code paths still work
    AVAILABLE = False
    _njit = None


def jit(function: Callable[..., Any]) -> Callable[..., Any]:
    """Compile a kernel (numba ``njit``, cached on disk, no GIL); without numba keep it as is."""
    if _njit is None:
        return function
    return _njit(cache=True, nogil=True)(function)


def enabled() -> bool:
    """Whether the compiled kernels are used: numba imports and ``MLSEMREG_KERNELS != numpy``."""
    return AVAILABLE and os.environ.get(ENV_SWITCH, '').strip().lower() != 'numpy'


def use_compiled(compiled: bool | None) -> bool:
    """Resolve a ``compiled`` argument: None follows :func:`enabled`; True needs numba."""
    if compiled is None:
        return enabled()
    if compiled and not AVAILABLE:
        raise RuntimeError('compiled kernels requested but numba is not installed')
    return bool(compiled)


_GOLDEN = -7046029254386353131  # 0x9E3779B97F4A7C15 as int64 (Fibonacci hashing)


# ----------------------------------------------------------------------------------
# Voxel grid: hash the integer keys in one pass, sort only the occupied voxels.
@jit
def _voxel_slots(
    points: np.ndarray, voxel_size: float, bits: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """
    Voxel of every point in first-seen order and each voxel's linear key, with a status.

    Status 0: done; 1: the key extent overflows int64; 2: more than ``2**(bits - 1)``
    voxels (the caller retries with a larger hash table).
    """
    n = points.shape[0]
    low = np.zeros(3, dtype=np.int64)
    high = np.zeros(3, dtype=np.int64)
    for i in range(n):  # keys are recomputed below: storing them costs more (fresh pages)
        for k in range(3):
            key = np.int64(np.floor(points[i, k] / voxel_size))
            if i == 0 or key < low[k]:
                low[k] = key
            if i == 0 or key > high[k]:
                high[k] = key
    extent = high - low + 1
    if float(extent[0]) * float(extent[1]) * float(extent[2]) >= 2.0**62:
        return np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int64), 1
    size = 1 << bits
    mask = size - 1
    table_key = np.full(size, -1, dtype=np.int64)  # linear key of each hash bucket
    table_slot = np.empty(size, dtype=np.int32)  # its voxel in first-seen order
    linear_of_slot = np.empty(size // 2, dtype=np.int64)
    slot = np.empty(n, dtype=np.int32)
    count, previous, previous_slot = 0, -1, -1
    for i in range(n):
        linear = 0
        for k in range(3):
            linear = linear * extent[k] + (np.int64(np.floor(points[i, k] / voxel_size)) - low[k])
        if linear == previous:  # scans are ordered: neighbours often share a voxel
            slot[i] = previous_slot
            continue
        bucket = ((linear * _GOLDEN) >> (64 - bits)) & mask  # multiplicative hash, top bits
        while table_key[bucket] >= 0 and table_key[bucket] != linear:
            bucket = (bucket + 1) & mask
        if table_key[bucket] < 0:
            if count == size // 2:  # keep the load at most 1/2
                return slot, linear_of_slot, 2
            table_key[bucket] = linear
            table_slot[bucket] = count
            linear_of_slot[count] = linear
            count += 1
        previous, previous_slot = linear, table_slot[bucket]
        slot[i] = previous_slot
    return slot, linear_of_slot[:count], 0


@jit
def _voxel_sums(
    points: np.ndarray, slot: np.ndarray, order: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Renumber the voxels by ``order`` and sum their points in point order."""
    count = order.shape[0]
    rank = np.empty(count, dtype=np.int64)
    for r in range(count):
        rank[order[r]] = r
    inverse = np.empty(slot.shape[0], dtype=np.int64)
    sums = np.zeros((count, 3))
    sizes = np.zeros(count, dtype=np.int64)
    for i in range(slot.shape[0]):  # in point order, as np.bincount sums: same rounding
        v = rank[slot[i]]
        inverse[i] = v
        sums[v, 0] += points[i, 0]
        sums[v, 1] += points[i, 1]
        sums[v, 2] += points[i, 2]
        sizes[v] += 1
    return inverse, sums, sizes


def voxel_grid(
    points: np.ndarray, voxel_size: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """
    Occupied voxels of ``points``: ``(inverse (N,), sums (V, 3), sizes (V,))``, or None.

    Voxels are numbered in lexicographic order of their integer keys
    ``floor(p / voxel_size)``, as :func:`mlsemreg_ros.core.features.features.voxel_groups`;
    ``sums`` are the coordinate sums in point order (so ``sums / sizes`` equals the
    NumPy centroids bit for bit). None when the key extent overflows int64 (the
    caller falls back to NumPy). Cost: one hash probe per point (one per run of
    consecutive points in the same voxel) and a sort of the V occupied voxels only.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if points.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    bits = max(10, int(points.shape[0] - 1).bit_length())  # table >= N: no retry if V <= N/2
    while True:
        slot, linear, status = _voxel_slots(points, float(voxel_size), bits)
        if status != 2:
            break
        bits += 2
    if status == 1:
        return None
    return _voxel_sums(points, slot, np.argsort(linear))  # NumPy's sort is the faster


@jit
def _majority(
    inverse: np.ndarray, label_index: np.ndarray, voxels: int, classes: int
) -> np.ndarray:
    table = np.zeros((voxels, classes), dtype=np.int32)
    for i in range(inverse.shape[0]):
        table[inverse[i], label_index[i]] += 1
    winner = np.empty(voxels, dtype=np.int64)
    for v in range(voxels):
        best = 0
        for c in range(1, classes):  # strictly greater: ties go to the smaller index
            if table[v, c] > table[v, best]:
                best = c
        winner[v] = best
    return winner


def majority(
    inverse: np.ndarray, label_index: np.ndarray, voxels: int, classes: int
) -> np.ndarray:
    """
    Index of the most frequent label of every voxel (ties: the smallest index).

    - ``inverse``: (N,) voxel of every point; ``label_index``: (N,) its label's index in
      ``[0, classes)`` (ascending label ids, so the smallest index is the smallest id).

    Returns (V,) int64. Memory: a dense (V, classes) int32 count table.
    """
    return _majority(
        np.ascontiguousarray(inverse, dtype=np.int64),
        np.ascontiguousarray(label_index, dtype=np.int64),
        int(voxels),
        int(classes),
    )


# ----------------------------------------------------------------------------------
# Deskew: exp(tau * twist) p for every point, in one pass (core/features/deskew.py).
class SegmentRows(NamedTuple):
    """
    A piecewise sweep motion as the deskew kernel reads it: one row per segment (M).

    A named tuple, so that the kernels take the whole motion as one argument. Segment ``k``
    starts at ``starts[k]`` s with the pose ``(rotation[k], offset[k])`` and moves by the
    twist of ``velocity[k]`` and ``rate[k]`` about ``axis[k]`` (``cross1 = axis x v``,
    ``cross2 = axis x cross1``; all zero but ``velocity`` when it does not turn).
    """

    starts: np.ndarray  # (M,) s
    velocity: np.ndarray  # (M, 3) m/s
    rate: np.ndarray  # (M,) rad/s
    axis: np.ndarray  # (M, 3)
    cross1: np.ndarray  # (M, 3)
    cross2: np.ndarray  # (M, 3)
    rotation: np.ndarray  # (M, 3, 3) the segment's start pose
    offset: np.ndarray  # (M, 3)

    @classmethod
    def of(cls, *rows: np.ndarray) -> SegmentRows:
        """Return the rows (in field order) as contiguous float64 arrays."""
        return cls(*(np.ascontiguousarray(row, dtype=np.float64) for row in rows))

    @classmethod
    def constant(
        cls,
        velocity: np.ndarray,
        rate: float,
        axis: np.ndarray,
        cross1: np.ndarray,
        cross2: np.ndarray,
    ) -> SegmentRows:
        """One segment from the stamp, at the identity: a constant twist."""
        return cls.of(
            np.zeros(1),
            np.reshape(velocity, (1, 3)),
            np.array([float(rate)]),
            np.reshape(axis, (1, 3)),
            np.reshape(cross1, (1, 3)),
            np.reshape(cross2, (1, 3)),
            np.eye(3)[None],
            np.zeros((1, 3)),
        )


def deskew_points(
    points: np.ndarray,
    times: np.ndarray,
    velocity: np.ndarray,
    rate: float,
    axis: np.ndarray,
    cross1: np.ndarray,
    cross2: np.ndarray,
    small_angle: float,
) -> np.ndarray:
    """
    Run the NumPy passes of :func:`mlsemreg_ros.core.features.deskew.deskew` in one loop.

    ``p' = R(tau) p + t(tau)`` for every point (Rodrigues about ``axis``, the left
    Jacobian's closed form with ``cross1 = axis x v`` and ``cross2 = axis x cross1``; when
    ``rate * max |tau|`` is below ``small_angle`` the translation is ``tau v`` alone): the
    one-segment case of :func:`deskew_piecewise_points`, whose start pose is the identity
    (exact for finite points). The same operations in the same order as the NumPy code,
    up to the last bit of ``sin``/``cos`` and of the dot product. Returns (N, 3) float64.
    """
    motion = SegmentRows.constant(velocity, rate, axis, cross1, cross2)
    segment = np.zeros(len(times), dtype=np.int64)
    return deskew_piecewise_points(points, times, segment, motion, small_angle)


@jit
def _deskew_piecewise(
    points: np.ndarray,
    times: np.ndarray,
    segment: np.ndarray,
    motion: SegmentRows,
    small_angle: float,
) -> np.ndarray:
    starts, velocity, rate, axis, cross1, cross2, rotation, offset = motion
    n, m = points.shape[0], starts.shape[0]
    # per segment, from its points: any rotation, the translation's series
    longest = np.zeros(m)
    rotate = np.zeros(m, dtype=np.bool_)
    for i in range(n):
        k = segment[i]
        tau = times[i] - starts[k]
        longest[k] = max(longest[k], abs(tau))
        if rate[k] != 0.0 and tau * rate[k] != 0.0:
            rotate[k] = True
    series = np.empty(m, dtype=np.bool_)
    for k in range(m):
        series[k] = rate[k] * longest[k] < small_angle
    out = np.empty((n, 3))
    t_last, k_last, cos, sin, tx, ty, tz = np.nan, -1, 1.0, 0.0, 0.0, 0.0, 0.0
    for i in range(n):
        k = segment[i]
        t = times[i] - starts[k]
        if t != t_last or k != k_last:  # times repeat along a sweep column
            t_last, k_last = t, k
            angle = t * rate[k]
            v, c1, c2 = velocity[k], cross1[k], cross2[k]
            tx, ty, tz = t * v[0], t * v[1], t * v[2]
            cos, sin = np.cos(angle), np.sin(angle)  # once for the series and the rotation
            if not series[k]:
                a = (0.0 if abs(angle) < small_angle else 1.0 - cos) / rate[k]
                b = (angle - sin) / rate[k]
                tx = tx + a * c1[0] + b * c2[0]
                ty = ty + a * c1[1] + b * c2[1]
                tz = tz + a * c1[2] + b * c2[2]
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if rotate[k]:
            e = axis[k]
            dot = x * e[0] + y * e[1] + z * e[2]
            one_minus = 1.0 - cos
            lx = x * cos + (e[1] * z - e[2] * y) * sin + dot * e[0] * one_minus + tx
            ly = y * cos + (e[2] * x - e[0] * z) * sin + dot * e[1] * one_minus + ty
            lz = z * cos + (e[0] * y - e[1] * x) * sin + dot * e[2] * one_minus + tz
        else:
            lx, ly, lz = x + tx, y + ty, z + tz
        R, o = rotation[k], offset[k]
        out[i, 0] = R[0, 0] * lx + R[0, 1] * ly + R[0, 2] * lz + o[0]
        out[i, 1] = R[1, 0] * lx + R[1, 1] * ly + R[1, 2] * lz + o[1]
        out[i, 2] = R[2, 0] * lx + R[2, 1] * ly + R[2, 2] * lz + o[2]
    return out


def deskew_piecewise_points(
    points: np.ndarray,
    times: np.ndarray,
    segment: np.ndarray,
    motion: SegmentRows,
    small_angle: float,
) -> np.ndarray:
    """
    Deskew every point by its segment of a piecewise motion, in one loop.

    Point ``i`` belongs to segment ``segment[i]`` (M segments of ``motion``, as
    :meth:`SegmentRows.of` gives them: contiguous float64); on segment
    ``k`` it is mapped by ``exp((tau - starts[k]) twist_k)`` (as for :func:`deskew_points`),
    then by the segment's start pose ``(rotation[k] (3, 3), offset[k] (3,))``. Whether a
    segment rotates and whether its translation takes the series are decided from its own
    points. The trigonometry and the translation are computed once per run of equal time:
    a sweep's points come column by column. Returns (N, 3) float64.
    """
    f64 = np.float64
    return _deskew_piecewise(
        np.ascontiguousarray(points, dtype=f64),
        np.ascontiguousarray(times, dtype=f64),
        np.ascontiguousarray(segment, dtype=np.int64),
        motion,
        float(small_angle),
    )


_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc mallopt parameters


def keep_freed_memory(mmap_threshold: int = 32 << 20, trim_threshold: int = 256 << 20) -> bool:
    """
    Opt in: let glibc keep freed memory in the heap instead of returning it at every free.

    Per frame the pipeline allocates and frees tens of MB of temporaries; with glibc's
    defaults many of them come from fresh ``mmap`` pages, and every first touch of a
    page is a page fault (~2 us here): ~2000 faults = 4 ms per FPFH call on a
    simulated scan. Raising ``M_MMAP_THRESHOLD`` and ``M_TRIM_THRESHOLD`` removes them
    (the resident size then stays at the peak working set). Process-wide; the same
    as starting the process with ``GLIBC_TUNABLES=glibc.malloc.mmap_threshold=...:
    glibc.malloc.trim_threshold=...``. Returns False where there is no glibc ``mallopt``.
    """
    name = ctypes.util.find_library('c')
    try:
        mallopt = ctypes.CDLL(name).mallopt if name else None
    except (OSError, AttributeError):
        mallopt = None
    if mallopt is None:
        return False
    return bool(
        mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))
        and mallopt(_M_TRIM_THRESHOLD, int(trim_threshold))
    )
