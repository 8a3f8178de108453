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
Semantic bird's-eye-view search: pose hypotheses that do not come from correspondences.

When every hypothesis of the estimator is refused (core/estimation/confidence.py), the true pose
was usually never among them: on dev pair 000007 with FPFH only 54 of 7902
correspondences are inliers, a slide along the street has ~100, and SC2-PCR seeds the
slide. The scans themselves still hold the answer (dense overlap 0.44 at the true pose,
0.10 at the slide), so this stage searches the scans directly, beyond the paper:

1. each scan becomes a stack of binary bird's-eye-view occupancy grids, one per class
   group of ``classes`` (static structure: building~fence, vegetation~trunk, ...), cells of
   ``cell_size``; every channel is scaled to unit norm, so the correlation of two channels
   is the cosine similarity of their occupied cells;
2. the source grids are rasterised per yaw (rotated points, one array assignment per chunk
   of yaws) and correlated with the target grids over every translation at once by FFT
   (summed over channels in the frequency domain), coarse to fine (:func:`yaw_search`):
   every ``coarse_factor x yaw_step`` first, then ``yaw_step`` around the
   ``coarse_yaws`` best coarse yaws; a yaw and the yaws a quarter, half and three
   quarters of a turn from it share one rasterisation and forward transform (the turned
   grid is the grid turned cell by cell, its correlation the grid's correlation with the
   target turned back: ``Correlator._turned_correlation``);
3. every yaw's ``peaks_per_yaw`` best local maxima within ``max_translation`` are pooled,
   suppressed within ``nms_rotation`` / ``nms_translation`` of a better peak, and the best
   ``hypotheses`` become ``z``-up poses ``Rz(yaw), (tx, ty, 0)``.

It assumes ``z``-up sensor frames and a mostly yaw motion (a ground vehicle); roll, pitch
and height are left to the refinement that follows (core/estimation/verification.py). The cost does
not depend on the keypoints: about ``(360 / (coarse_factor x yaw_step) + coarse_yaws x
(coarse_factor - 1)) x channels`` FFTs of ``next_fast_len(2 (radius + max_translation) /
cell_size)`` squared, forward and back; the yaws a quarter turn apart need one forward
transform (the coarse yaws of a 6 deg step all group by four).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import time
from typing import TYPE_CHECKING

from mlsemreg_ros.core.estimation import kernels
from mlsemreg_ros.core.estimation.config import BevSearchConfig, class_rule_names
from mlsemreg_ros.core.estimation.verification import (
    LabelCompatibility,
    refine_starts,
    score_hypotheses,
)
from mlsemreg_ros.core.features import kernels as compiled
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.poses import distinct_hypotheses
from mlsemreg_ros.core.results import PreparedScan, VerificationResult
import numpy as np
from scipy import fft, ndimage
from scipy.spatial.transform import Rotation

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig

#: Yaws rasterised and transformed together (bounds the memory of one chunk).
_YAW_CHUNK = 12


@dataclass(frozen=True)
class BevGrid:
    """Geometry of the search grids (shared by source and target)."""

    cell_size: float  # metres
    radius: float  # source points farther than this (xy) are left out
    max_translation: float  # largest |t_xy| searched
    size: int  # cells per side; the sensor sits at cell (size // 2, size // 2)

    @classmethod
    def make(cls, cell_size: float, radius: float, max_translation: float) -> BevGrid:
        """Make a grid large enough that no shift up to ``max_translation`` wraps around."""
        cells = int(np.ceil(2.0 * (radius + max_translation) / cell_size)) + 2
        return cls(cell_size, radius, max_translation, fft.next_fast_len(cells, real=True))


def channel_of_labels(channels: list[np.ndarray], num_classes: int) -> np.ndarray:
    """``(num_classes,)`` channel index of every learning id, -1 for classes not searched."""
    lookup = np.full(num_classes, -1, dtype=np.int64)
    for index, ids in enumerate(channels):
        lookup[np.asarray(ids, dtype=np.int64)] = index
    return lookup


def occupancy(
    xy: np.ndarray, channel: np.ndarray, grid: BevGrid, num_channels: int, limit: float
) -> np.ndarray:
    """
    ``(num_channels, size, size)`` float32 binary occupancy of ``xy`` points, unit norm.

    ``channel``: per point, its channel (``>= 0``); points with ``|xy|_inf > limit`` are
    left out.
    """
    return _rasterise(xy[None], channel, grid, num_channels, limit)[0]


def _rasterise(
    xy: np.ndarray, channel: np.ndarray, grid: BevGrid, num_channels: int, limit: float
) -> np.ndarray:
    """Occupancy of ``(Y, n, 2)`` point sets sharing one channel vector: ``(Y, C, s, s)``."""
    count, size = xy.shape[0], grid.size
    half = size // 2
    # the grid holds |xy|_inf < half cells; limit <= radius + max_translation keeps inside
    inside = (np.abs(xy) <= min(limit, (half - 1) * grid.cell_size)).all(axis=2)
    cells = np.floor(xy[inside] / grid.cell_size).astype(np.int64) + half
    plane = (np.arange(count)[:, None] * num_channels + channel[None, :])[inside]
    flat = (plane * size + cells[:, 0]) * size + cells[:, 1]
    grids = np.zeros((count * num_channels, size * size), dtype=np.float32)
    grids.reshape(-1)[flat] = 1.0
    per_plane = grids.sum(axis=1)
    scale = np.zeros_like(per_plane)
    np.divide(1.0, np.sqrt(per_plane), out=scale, where=per_plane > 0)
    grids *= scale[:, None]
    return grids.reshape(count, num_channels, size, size)


def _channels(labels: np.ndarray, lookup: np.ndarray) -> np.ndarray:
    """Channel of every label; -1 for classes not searched and for ids outside the map."""
    labels = np.asarray(labels, dtype=np.int64)
    known = (labels >= 0) & (labels < lookup.size)
    return np.where(known, lookup[np.where(known, labels, 0)], -1)


def _thinned(
    xy: np.ndarray, channel: np.ndarray, cell_size: float
) -> tuple[np.ndarray, np.ndarray]:
    """One point (the first) per ``cell_size`` cell and channel: rotating fewer points."""
    if len(xy) == 0:
        return xy, channel
    cells = np.floor(xy / cell_size).astype(np.int64)
    cells -= cells.min(axis=0)
    extent = cells.max(axis=0) + 1
    # one integer per (channel, x cell, y cell), ordered as the rows (np.unique(axis=0))
    key = (channel.astype(np.int64) * extent[0] + cells[:, 0]) * extent[1] + cells[:, 1]
    _, first = np.unique(key, return_index=True)
    return xy[first], channel[first]


def z_up_poses(yaw_deg: np.ndarray, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """``(Y, 4, 4)`` poses ``Rz(yaw), (tx, ty, 0)``."""
    transforms = np.tile(np.eye(4), (len(yaw_deg), 1, 1))
    transforms[:, :3, :3] = Rotation.from_euler(
        'z', np.reshape(yaw_deg, (-1, 1)), degrees=True
    ).as_matrix()
    transforms[:, 0, 3], transforms[:, 1, 3] = tx, ty
    return transforms


class Correlator:
    """
    The target's grids in the frequency domain, correlated with the source at given yaws.

    ``peaks(yaws, k)`` returns the best ``k`` translations of every yaw as ``(P, 4)`` rows
    ``(score, yaw_deg, tx, ty)``; ``score`` is the summed per-channel cosine similarity of
    the occupied cells (at most the number of channels). Only translations with
    ``|t|_inf <= max_translation``.
    """

    def __init__(
        self,
        source_xy: np.ndarray,
        source_channel: np.ndarray,
        target_xy: np.ndarray,
        target_channel: np.ndarray,
        grid: BevGrid,
        num_channels: int,
    ) -> None:
        """Rasterise and transform the target once."""
        self.source_xy, self.source_channel = source_xy, source_channel
        self.grid, self.num_channels = grid, num_channels
        limit = grid.radius + grid.max_translation
        target = occupancy(target_xy, target_channel, grid, num_channels, limit)
        self.target_spectrum = fft.rfft2(target, workers=-1)
        self._target = target
        self._turned_targets: np.ndarray | None = None
        self.shift = np.fft.fftfreq(grid.size, d=1.0 / grid.size) * grid.cell_size  # metres
        # the reachable shifts, |shift| <= max_translation: in grid order (ascending cell)
        # and as one block in shift order (ascending shift), for the local maxima
        self.reachable = np.flatnonzero(np.abs(self.shift) <= grid.max_translation)
        by_shift = np.argsort(self.shift[self.reachable], kind='stable')
        self.to_shift_order = by_shift
        self.to_grid_order = np.argsort(by_shift, kind='stable')
        # the grid rows a source point within grid.radius can occupy (_rasterise)
        half, reach = grid.size // 2, int(np.floor(grid.radius / grid.cell_size))
        self.source_rows = (max(half - reach - 2, 0), min(half + reach + 2, grid.size))

    def peaks(self, yaws: np.ndarray, peaks_per_yaw: int) -> np.ndarray:
        """
        Best ``peaks_per_yaw`` local maxima of the correlation at every yaw (deg).

        Rows yaw by yaw, in the order of ``yaws``. Yaws a quarter, half and three quarters
        of a turn from one another, asked for together, share one rasterisation and one
        forward transform (:meth:`_turned_sums`).
        """
        yaws = np.asarray(yaws, dtype=np.float64)
        group = quarter_turn_groups(yaws)
        rows = [np.zeros((0, 4))] * yaws.size
        for first in range(0, len(group), _YAW_CHUNK):
            members = group[first:][:_YAW_CHUNK]  # (B, 4): the base yaw, +90, +180, +270
            rotation = Rotation.from_euler(
                'z', yaws[members[:, 0], None], degrees=True
            ).as_matrix()[:, :2, :2]
            rotated = self.source_xy[None] @ rotation.transpose(0, 2, 1)  # (B, n, 2)
            source = self._source_window(rotated)
            correlation, order = self._turned_correlation(source, members)
            found = self._local_peaks(correlation, yaws[order], peaks_per_yaw)
            for index, yaw_rows in zip(order, found, strict=True):
                rows[index] = yaw_rows
        return np.concatenate([np.zeros((0, 4)), *rows])

    def _source_window(self, rotated: np.ndarray) -> np.ndarray:
        """
        ``(Y, C, w, w)`` occupancy of rotated source points, the window of rows and columns.

        The grids of :func:`_rasterise` (``limit = grid.radius``) but only their rows and
        columns ``source_rows`` (nothing lies beyond): cell ``(i, j)`` at ``(i - low, j -
        low)``; the same cells and the same unit-norm scale.
        """
        grid, count = self.grid, rotated.shape[0]
        low, high = self.source_rows
        width, half = high - low, grid.size // 2
        limit = min(grid.radius, (half - 1) * grid.cell_size)
        inside = (np.abs(rotated) <= limit).all(axis=2)
        cells = np.floor(rotated[inside] / grid.cell_size).astype(np.int64) + (half - low)
        plane = (np.arange(count)[:, None] * self.num_channels + self.source_channel[None, :])[
            inside
        ]
        kept = ((cells >= 0) & (cells < width)).all(axis=1)  # always (source_rows), kept safe
        flat = (plane[kept] * width + cells[kept, 0]) * width + cells[kept, 1]
        grids = np.zeros((count * self.num_channels, width * width), dtype=np.float32)
        grids.reshape(-1)[flat] = 1.0
        per_plane = grids.sum(axis=1)
        scale = np.zeros_like(per_plane)
        np.divide(1.0, np.sqrt(per_plane), out=scale, where=per_plane > 0)
        grids *= scale[:, None]
        return grids.reshape(count, self.num_channels, width, width)

    def _turned_correlation(
        self, source: np.ndarray, members: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        Correlations of windowed source grids and their quarter turns, at the reachable shifts.

        ``source`` ``(B, C, w, w)`` (:meth:`_source_window`), ``members`` ``(B, 4)`` the yaw
        indices of each grid turned by 0, 1, 2, 3 quarter turns (-1: not asked). Returns
        ``(Y, w', w')`` float32 correlations (reachable rows and columns in grid order) and
        the ``(Y,)`` yaw index of each.

        A quarter turn moves a point's cell ``(i, j)`` (rows: x, columns: y) to
        ``(m - j, i)``, ``m = 2 half - 1`` (``floor(-x) = -floor(x) - 1``: the same cell but
        for a point on a cell border). The correlation of the turned grid with the target
        is the grid's correlation with the target turned back (:meth:`turned_targets`),
        read at the turned shifts; the window moves the grid by ``low`` along both axes.
        One forward transform serves the four turns.
        """
        size, (low, _) = self.grid.size, self.source_rows
        spectrum = fft.rfft(source, n=size, axis=-1, workers=-1)
        spectrum = fft.fft(spectrum, n=size, axis=-2, workers=-1, overwrite_x=True)
        wanted = members >= 0
        # the sums quarter by quarter, each quarter's grids in order: contiguous blocks
        slot = np.full(wanted.shape, -1, dtype=np.int64)
        slot.T[wanted.T] = np.arange(int(wanted.sum()))
        sums = self._turned_sums(spectrum, slot)
        ahead = (self.reachable + low) % size  # the shift t read at t + low
        back = (low - self.reachable) % size  # -t
        # quarter q: (rows, columns) read, and whether the map is transposed after
        reads = (
            (ahead, ahead, False),
            (ahead, back, True),
            (back, back, False),
            (back, ahead, True),
        )
        parts, order, start = [], [], 0
        for quarter, (rows, columns, transposed) in enumerate(reads):
            asked = wanted[:, quarter]
            if asked.any():
                stop = start + int(asked.sum())
                found = self._inverse(sums[start:stop], rows, columns)
                parts.append(
                    np.ascontiguousarray(found.transpose(0, 2, 1)) if transposed else found
                )
                order.append(members[asked, quarter])
                start = stop
        return np.concatenate(parts), np.concatenate(order)

    def turned_targets(self) -> np.ndarray:
        """
        ``(4, C, s, h)`` spectra of the target grid turned back by 0-3 quarter turns.

        Quarter ``q``'s correlation ``c_q(t) = sum_x g_q(x) T(x + t)`` of the source grid
        ``g`` turned by ``q`` is ``sum_x g(x) T_q(x + t')``: ``T_1(p, r) = T(m - r, p)``
        read at ``t' = (t_y, -t_x)`` (transposed), ``T_2(p, r) = T(m - p, m - r)`` at
        ``-t``, ``T_3(p, r) = T(r, m - p)`` at ``(-t_y, t_x)``; a permutation of cells,
        exact. Made on first use, once per target.
        """
        if self._turned_targets is None:
            size = self.grid.size
            flip = (2 * (size // 2) - 1 - np.arange(size)) % size  # m - p
            target = self._target
            turned = [
                target[:, flip].transpose(0, 2, 1),  # T(m - r, p)
                target[:, flip][:, :, flip],  # T(m - p, m - r)
                target.transpose(0, 2, 1)[:, flip],  # T(r, m - p)
            ]
            spectra = [self.target_spectrum]
            spectra += [fft.rfft2(np.ascontiguousarray(t), workers=-1) for t in turned]
            self._turned_targets = np.stack(spectra)
        return self._turned_targets

    def _turned_sums(self, spectrum: np.ndarray, slot: np.ndarray) -> np.ndarray:
        """:func:`~mlsemreg_ros.core.estimation.kernels.bev_channel_sums` (NumPy without numba)."""
        targets = self.turned_targets()
        if compiled.enabled():
            floats = kernels.bev_channel_sums(
                spectrum.view(np.float32), targets.view(np.float32), slot
            )
            return floats.view(np.complex64)
        # the kernel's arithmetic on the real and imaginary parts, in its order
        _, channels, size, half = spectrum.shape
        sums = np.zeros((int(slot.max()) + 1, size, half), dtype=np.complex64)
        for b, q in zip(*np.nonzero(slot >= 0), strict=True):  # a few dozen grids
            real = np.zeros((size, half), dtype=np.float32)
            imaginary = np.zeros_like(real)
            for channel in range(channels):  # a few channels: not a loop over points
                re, im = spectrum[b, channel].real, spectrum[b, channel].imag
                t_re, t_im = targets[q, channel].real, targets[q, channel].imag
                real += re * t_re + im * t_im
                imaginary += re * t_im - im * t_re
            sums[slot[b, q]] = real + 1j * imaginary
        return sums

    def _local_peaks(
        self, correlation: np.ndarray, yaw: np.ndarray, peaks_per_yaw: int
    ) -> list[np.ndarray]:
        """Return the best local maxima of each ``(w, w)`` correlation: ``(P, 4)`` rows per yaw."""
        if compiled.enabled():
            y, u, v, value = kernels.bev_local_peaks(
                correlation, self.to_grid_order, self.to_shift_order, peaks_per_yaw
            )
            found = self._rows(value, yaw[y], u, v)
            return np.split(found, np.searchsorted(y, np.arange(1, yaw.size)))
        # local maxima over the reachable block in shift order; -inf beyond it (as the full
        # grid with the unreachable shifts at -inf: the block does not wrap)
        in_shift = correlation[:, self.to_shift_order][:, :, self.to_shift_order]
        local_max = ndimage.maximum_filter(in_shift, size=(1, 3, 3), mode='constant', cval=-np.inf)
        is_peak = in_shift == local_max
        is_peak = is_peak[:, self.to_grid_order][:, :, self.to_grid_order]
        width = self.reachable.size
        per_yaw = []
        for y in range(yaw.size):  # one small top-k per yaw
            flat = np.flatnonzero(is_peak[y])
            values = correlation[y].ravel()[flat]
            best = flat[np.argsort(-values, kind='stable')[:peaks_per_yaw]]
            u, v = np.unravel_index(best, (width, width))
            per_yaw.append(self._rows(correlation[y][u, v], np.full(best.size, yaw[y]), u, v))
        return per_yaw

    def _rows(
        self, value: np.ndarray, yaw: np.ndarray, u: np.ndarray, v: np.ndarray
    ) -> np.ndarray:
        """``(P, 4)`` rows ``(score, yaw_deg, tx, ty)`` of reachable cells ``(u, v)``."""
        shift = self.shift[self.reachable]
        return np.column_stack([value, yaw, shift[u], shift[v]])

    def _inverse(self, spectrum: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """``(Y, w, w)``: ``(Y, s, s // 2 + 1)`` back, at grid ``rows`` and ``columns`` only."""
        size = self.grid.size
        # only the rows and columns read: the row transform first, then the rows read
        back = fft.ifft(spectrum, axis=-2, workers=-1, overwrite_x=True)[:, rows]
        correlation = fft.irfft(back, n=size, axis=-1, workers=-1, overwrite_x=True)
        return np.ascontiguousarray(correlation[:, :, columns])


def quarter_turn_groups(yaws: np.ndarray) -> np.ndarray:
    """
    Group the yaws (deg) a quarter turn apart: ``(G, 4)`` indices, -1 where not asked.

    Row ``g``: a base yaw (the first yaw of no earlier group), then the yaws 90, 180 and
    270 deg after it (within 1e-9 deg; the first such yaw not yet grouped). Every index
    appears once; the base yaws in the order of ``yaws``.
    """
    # every yaw's candidates a quarter, half and three quarters on, found at once
    turn = np.mod(yaws[None, :] - yaws[:, None] - 90.0 * np.arange(1, 4)[:, None, None], 360.0)
    near = np.abs(np.mod(turn + 180.0, 360.0) - 180.0) <= 1e-9  # (3, n, n)
    candidates = [[np.flatnonzero(row).tolist() for row in quarter] for quarter in near]
    taken = [False] * yaws.size
    groups = []
    for index in range(yaws.size):  # a few hundred yaws at most: not a loop over points
        if taken[index]:
            continue
        taken[index] = True
        row = [index, -1, -1, -1]
        for quarter in range(1, 4):
            match = next((j for j in candidates[quarter - 1][index] if not taken[j]), -1)
            if match >= 0:
                row[quarter] = match
                taken[match] = True
        groups.append(row)
    return np.asarray(groups, dtype=np.int64).reshape(-1, 4)


def yaw_search(
    correlator: Correlator,
    yaw_step: float,
    peaks_per_yaw: int,
    coarse_factor: int,
    coarse_yaws: int,
) -> np.ndarray:
    """
    Peaks over 360 deg of yaw, coarse to fine.

    With ``coarse_factor`` > 1 every ``coarse_factor x yaw_step`` is searched first, and
    only around the ``coarse_yaws`` yaws with the best peaks the steps in between
    (``yaw_step``); else every ``yaw_step``. Returns the pooled ``(score, yaw, tx, ty)``.
    """
    if coarse_factor <= 1:
        return correlator.peaks(np.arange(0.0, 360.0, yaw_step), peaks_per_yaw)
    coarse_step = coarse_factor * yaw_step
    coarse = correlator.peaks(np.arange(0.0, 360.0, coarse_step), peaks_per_yaw)
    if coarse.size == 0:
        return coarse
    yaws, first = np.unique(coarse[:, 1], return_index=True)
    best = np.maximum.reduceat(coarse[:, 0], first) if first.size else first
    kept = yaws[np.argsort(-best, kind='stable')[:coarse_yaws]]
    offsets = yaw_step * np.arange(1, (coarse_factor - 1) // 2 + 1)
    around = np.concatenate([kept[:, None] - offsets, kept[:, None] + offsets], axis=1)
    fine = np.unique(np.round(np.mod(around.ravel(), 360.0), 9))
    return np.concatenate([coarse, correlator.peaks(fine, peaks_per_yaw)])


def bev_hypotheses(
    source_points: np.ndarray,
    source_labels: np.ndarray,
    target_points: np.ndarray,
    target_labels: np.ndarray,
    channel_lookup: np.ndarray,
    config: BevSearchConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """
    ``z``-up pose hypotheses ``T_target_source`` of two labeled scans, best first.

    - ``*_points``: ``(N, 3)`` sensor-frame points; ``*_labels``: ``(N,)`` learning ids.
    - ``channel_lookup``: :func:`channel_of_labels` (-1: class not searched).
    - ``config``: the ``bev_search`` section (grid, yaws, peaks, suppression).

    Peaks within ``nms_rotation`` and ``nms_translation`` of a better one are dropped by
    :func:`~mlsemreg_ros.core.poses.distinct_hypotheses`, as the estimator's hypotheses.

    Returns ``(transforms (H, 4, 4), scores (H,))``; empty when a scan has no searched
    point.
    """
    num_channels = int(channel_lookup.max()) + 1 if channel_lookup.size else 0
    empty = np.zeros((0, 4, 4)), np.zeros(0)
    if num_channels == 0:
        return empty
    source_channel = _channels(source_labels, channel_lookup)
    target_channel = _channels(target_labels, channel_lookup)
    source_used, target_used = source_channel >= 0, target_channel >= 0
    if not source_used.any() or not target_used.any():
        return empty
    grid = BevGrid.make(config.cell_size, config.radius, config.max_translation)
    source_xy, source_channel = _thinned(
        source_points[source_used, :2], source_channel[source_used], config.cell_size / 2.0
    )
    correlator = Correlator(
        source_xy,
        source_channel,
        target_points[target_used, :2],
        target_channel[target_used],
        grid,
        num_channels,
    )
    peaks = yaw_search(
        correlator,
        config.yaw_step,
        config.peaks_per_yaw,
        config.coarse_factor,
        config.coarse_yaws,
    )
    peaks = peaks[peaks[:, 0] > 0]
    if peaks.size == 0:
        return empty
    peaks = peaks[np.argsort(-peaks[:, 0], kind='stable')]
    poses = z_up_poses(peaks[:, 1], peaks[:, 2], peaks[:, 3])
    kept = distinct_hypotheses(
        poses, config.hypotheses, config.nms_rotation, config.nms_translation
    )
    return poses[kept], peaks[kept, 0]


def channel_lookup(label_map: LabelMap, config: BevSearchConfig) -> np.ndarray:
    """:func:`channel_of_labels` of ``config.classes`` (unknown names raise ConfigError)."""
    groups = [label_map.ids_of(class_rule_names(rule)) for rule in config.classes]
    return channel_of_labels(groups, label_map.num_classes)


def search_scans(
    source: PreparedScan,
    target: PreparedScan,
    src: np.ndarray,
    dst: np.ndarray,
    config: RegistrationConfig,
    labels: LabelCompatibility,
    lookup: np.ndarray,
) -> VerificationResult | None:
    """
    BEV hypotheses of two prepared scans, refined on the correspondences and verified.

    - ``src``, ``dst``: ``(K, 3)`` correspondences (the refinement's data).
    - ``labels``: the verification's label rule; ``lookup``: :func:`channel_lookup`.

    Every peak is refined with SC2-PCR's post-refinement
    (:func:`~mlsemreg_ros.core.estimation.verification.refine_starts`) and scored like the
    estimator's hypotheses; the best score wins (no ``min_gain``: no peak is preferred).
    Returns ``None`` when no peak was found; ``diagnostics`` holds ``bev_search_*``.
    """
    search = config.bev_search
    tick = time.perf_counter()
    peaks, peak_scores = bev_hypotheses(
        source.points, source.labels, target.points, target.labels, lookup, search
    )
    peaks_ms = 1e3 * (time.perf_counter() - tick)
    if len(peaks) == 0:
        return None
    refined = refine_starts(peaks, src, dst, config.estimator)
    verification = dataclasses.replace(config.verification, min_gain=0.0)
    result = score_hypotheses(
        refined,
        np.arange(len(refined)),
        src,
        dst,
        source,
        target,
        verification,
        config.estimator,
        labels,
        origin='bev_search',
    )
    chosen = result.hypotheses[result.chosen]
    result.diagnostics = {
        'bev_search_peaks': len(refined),
        'bev_search_peaks_ms': peaks_ms,
        'bev_search_chosen_peak': chosen.rank,
        'bev_search_chosen_correlation': float(peak_scores[chosen.rank]),
        'bev_search_inliers': chosen.num_inliers,
        'bev_search_overlap': chosen.overlap,
        'bev_search_label_agreement': chosen.label_agreement,
        'bev_search_score': chosen.score,
    }
    return result
