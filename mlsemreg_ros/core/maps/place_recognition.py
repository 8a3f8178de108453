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
Place recognition: a semantic scan context per keyframe, candidates by ring key (docs/maps.md).

The descriptor of a scan (sensor frame, z up) is a polar grid around the sensor,
``map.rings`` rings of ``map.max_radius / map.rings`` metres by ``map.sectors`` sectors,
one binary occupancy channel per class group of ``bev_search.classes`` (the static
structure: buildings, vegetation, poles); each channel grid is scaled to unit norm.

- **Ring key** ``(channels x rings,)``: the share of occupied sectors of every ring and
  channel. A yaw of the sensor permutes the sectors of a ring and leaves it unchanged, so
  the ring key is rotation-invariant; the map's ring keys sit in a SciPy ``cKDTree``
  (sub-linear nearest-neighbour search).
- **Scan context similarity**: the best cosine similarity of two descriptors over every
  sector shift (a circular cross-correlation along the sectors, by FFT, for all shortlisted
  keyframes at once); it also gives the yaw between the scans.

:func:`shortlist` keeps the ``map.descriptor_candidates`` nearest ring keys, re-ranks them
by the scan context similarity and returns the best ``map.candidates`` keyframes that lie
at least ``map.candidate_separation`` apart (registering onto two neighbouring keyframes
would give the same answer twice).
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.config import MapConfig
import numpy as np
from scipy import fft
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class PlaceDescriptor:
    """Semantic scan context of one scan and its rotation-invariant ring key."""

    context: np.ndarray  # (channels, rings, sectors) float32, every channel of unit norm
    ring_key: np.ndarray  # (channels * rings,) float32

    @property
    def nbytes(self) -> int:
        """Memory of the arrays."""
        return int(self.context.nbytes + self.ring_key.nbytes)


def describe(
    points: np.ndarray, labels: np.ndarray, channel_of_label: np.ndarray, config: MapConfig
) -> PlaceDescriptor:
    """
    Return the semantic scan context of a scan (points (N, 3) sensor frame, learning ids).

    ``channel_of_label``: per learning id its channel (-1: left out), e.g.
    :func:`mlsemreg_ros.core.estimation.bev_search.channel_lookup`.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ids = np.asarray(labels, dtype=np.int64).reshape(-1)
    channels = int(channel_of_label.max()) + 1 if channel_of_label.size else 0
    channels = max(channels, 1)
    grid = np.zeros((channels, config.rings, config.sectors), dtype=np.float32)
    valid = (ids >= 0) & (ids < channel_of_label.size)
    channel = np.full(ids.shape, -1, dtype=np.int64)
    channel[valid] = channel_of_label[ids[valid]]
    radius = np.hypot(points[:, 0], points[:, 1])
    keep = (channel >= 0) & (radius < config.max_radius) & np.isfinite(radius)
    ring = (radius[keep] * (config.rings / config.max_radius)).astype(np.int64)
    angle = np.arctan2(points[keep, 1], points[keep, 0])
    sector = ((angle + np.pi) * (config.sectors / (2.0 * np.pi))).astype(np.int64)
    sector = np.minimum(sector, config.sectors - 1)
    grid[channel[keep], np.minimum(ring, config.rings - 1), sector] = 1.0
    ring_key = grid.mean(axis=2).reshape(-1)
    norms = np.linalg.norm(grid.reshape(channels, -1), axis=1)
    grid /= np.where(norms > 0, norms, 1.0)[:, None, None]
    return PlaceDescriptor(grid, ring_key.astype(np.float32))


def context_similarity(
    query: PlaceDescriptor, contexts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """
    Best similarity over the sector shifts of ``query`` against ``contexts`` (M, C, R, S).

    Returns ``(similarity (M,), yaw (M,) radians)``: the mean over channels of the cosine
    similarity at the best shift (1 for identical scans), and the yaw that rotates the query
    onto the keyframe at that shift (``T_keyframe_query`` is about ``Rz(yaw)`` there).
    """
    contexts = np.asarray(contexts, dtype=np.float32)
    if contexts.shape[0] == 0:
        return np.zeros(0), np.zeros(0)
    sectors = contexts.shape[-1]
    spectrum = fft.rfft(contexts, axis=-1) * np.conj(fft.rfft(query.context, axis=-1))[None]
    # correlation[m, s] = sum_c,r sum_k keyframe[k] * query[k - s]: query turned by s sectors
    correlation = fft.irfft(spectrum.sum(axis=(1, 2)), n=sectors, axis=-1)
    channels = max(contexts.shape[1], 1)
    best = np.argmax(correlation, axis=1)
    similarity = correlation[np.arange(len(best)), best] / channels
    return similarity, best * (2.0 * np.pi / sectors)


@dataclass(frozen=True)
class Candidate:
    """A keyframe worth registering onto."""

    index: int  # position in the list of descriptors searched
    similarity: float  # scan context similarity (1: identical)
    yaw: float  # radians, query onto keyframe


class PlaceIndex:
    """Ring keys of a set of keyframes in a KD-tree; the scan contexts for re-ranking."""

    def __init__(self, descriptors: list[PlaceDescriptor], positions: np.ndarray) -> None:
        """``descriptors`` and ``positions`` (K, 3) of the keyframes (map frame)."""
        self.positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if len(descriptors) != len(self.positions):
            raise ValueError(f'{len(descriptors)} descriptors but {len(self.positions)} positions')
        self.contexts = (
            np.stack([d.context for d in descriptors]) if descriptors else np.zeros((0, 1, 1, 1))
        )
        keys = np.stack([d.ring_key for d in descriptors]) if descriptors else np.zeros((0, 1))
        self.tree = cKDTree(keys) if descriptors else None

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    def shortlist(
        self,
        query: PlaceDescriptor,
        config: MapConfig,
        allowed: np.ndarray | None = None,
    ) -> list[Candidate]:
        """
        Return the best ``config.candidates`` keyframes for ``query`` (module docstring).

        ``allowed``: optional (K,) bool mask of the keyframes that may be returned (loop
        closure leaves out the recent ones); the KD-tree is then asked for more
        neighbours so that the shortlist is still ``descriptor_candidates`` long. When the
        shortlist holds fewer than ``candidates`` places at least ``candidate_separation``
        apart (many keyframes of one place), it is doubled until it does or holds every
        keyframe.
        """
        if self.tree is None:
            return []
        count = len(self)
        excluded = 0
        if allowed is not None:
            allowed = np.asarray(allowed, dtype=bool)
            if not allowed.any():
                return []
            excluded = int(count - allowed.sum())
        pool = min(config.descriptor_candidates, count)
        while True:
            # enough neighbours that `pool` allowed ones are among them (at most all)
            _, neighbours = self.tree.query(query.ring_key, k=min(count, pool + excluded))
            neighbours = np.atleast_1d(neighbours)
            neighbours = neighbours[neighbours < count]
            if allowed is not None:
                neighbours = neighbours[allowed[neighbours]][:pool]
            chosen = self._spread(query, neighbours, config)
            if len(chosen) >= config.candidates or pool + excluded >= count:
                return chosen
            pool *= 2

    def _spread(
        self, query: PlaceDescriptor, neighbours: np.ndarray, config: MapConfig
    ) -> list[Candidate]:
        """Re-rank ``neighbours`` by scan context; keep the best ones that lie apart."""
        similarity, yaw = context_similarity(query, self.contexts[neighbours])
        order = np.argsort(-similarity, kind='stable')
        positions = self.positions[neighbours[order]]
        open_ = np.ones(len(order), dtype=bool)  # not within the separation of a chosen one
        chosen: list[Candidate] = []
        # greedy in similarity order: take the best open one, close every one near it
        while len(chosen) < config.candidates and open_.any():
            at = int(np.argmax(open_))
            i = order[at]
            chosen.append(Candidate(int(neighbours[i]), float(similarity[i]), float(yaw[i])))
            open_[at] = False
            if config.candidate_separation > 0:
                gap = np.linalg.norm(positions - positions[at], axis=1)
                open_ &= gap >= config.candidate_separation
        return chosen
