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
The keyframe store: accepted labeled keyframes in the map frame, bounded (docs/maps.md).

A keyframe keeps what a map folder holds (voxelized points in its sensor frame, learning
ids, ``T_map_keyframe``, stamp). What is derived from it is recomputed when needed and
cached: its place descriptor (:mod:`mlsemreg_ros.core.maps.place_recognition`, dropped when
``map`` or ``bev_search`` change) and its prepared scan for registration (an LRU cache of
``map.prepared_cache`` scans, since a prepared scan with descriptors and KD-trees is many
times the size of its points).

Bounds: at most ``map.max_keyframes`` keyframes and ``map.max_memory_mb`` of points,
labels and descriptors; beyond either, the most redundant keyframe (the one closest to
another keyframe) is dropped.
"""

from __future__ import annotations

import collections
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
import threading
from typing import Any

from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation import bev_search
from mlsemreg_ros.core.maps.place_recognition import describe, PlaceDescriptor, PlaceIndex
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
import numpy as np
from scipy.spatial import cKDTree


@dataclass
class StoredKeyframe:
    """One map keyframe: its labeled scan (sensor frame), its pose in the map and its stamp."""

    keyframe_id: int  # unique in its store, increasing in insertion order
    points: np.ndarray  # (N, 3) float32, sensor frame, voxelized
    labels: np.ndarray  # (N,) uint32 learning ids
    T_map_keyframe: np.ndarray  # (4, 4) float64
    stamp_ns: int = 0
    descriptor: PlaceDescriptor | None = field(default=None, repr=False)

    @property
    def nbytes(self) -> int:
        """Memory of its arrays (points, labels, pose, descriptor)."""
        extra = self.descriptor.nbytes if self.descriptor is not None else 0
        return int(self.points.nbytes + self.labels.nbytes + self.T_map_keyframe.nbytes + extra)

    @property
    def position(self) -> np.ndarray:
        """Return the sensor position in the map frame, shape (3,)."""
        return self.T_map_keyframe[:3, 3]


class KeyframeStore:
    """Keyframes of a map, bounded by count and memory; descriptors and prepared scans cached."""

    def __init__(
        self, config: RegistrationConfig | None = None, label_map: LabelMap | None = None
    ) -> None:
        """Store for ``config`` (its ``map`` and ``bev_search`` sections)."""
        self.label_map = label_map if label_map is not None else LabelMap.load()
        self._keyframes: collections.OrderedDict[int, StoredKeyframe] = collections.OrderedDict()
        self._prepared: collections.OrderedDict[int, PreparedScan] = collections.OrderedDict()
        self._cache_lock = threading.RLock()  # the cache is filled ahead (prepare_ahead)
        # other derived data by key (e.g. submap clouds), dropped whenever the store changes
        self._derived: collections.OrderedDict[Any, Any] = collections.OrderedDict()
        self._generation = 0  # counts the changes that drop _derived
        self._index: PlaceIndex | None = None
        self._index_ids: list[int] = []
        self._next_id = 0
        self._bytes = 0
        self.dropped = 0  # keyframes dropped by the bounds
        self.config = config if config is not None else RegistrationConfig()

    # -- configuration -------------------------------------------------------------
    @property
    def config(self) -> RegistrationConfig:
        """Return the configuration in use."""
        return self._config

    @config.setter
    def config(self, config: RegistrationConfig) -> None:
        old = getattr(self, '_config', None)
        self._config = config
        self._channels = bev_search.channel_lookup(self.label_map, config.bev_search)
        if old is None:
            return
        if old != config:
            self._changed()
        if old.map != config.map or old.bev_search != config.bev_search:
            for keyframe in self._keyframes.values():  # descriptors: recomputed when needed
                self._bytes -= keyframe.descriptor.nbytes if keyframe.descriptor else 0
                keyframe.descriptor = None
            self._index = None
        if any(
            getattr(old, s) != getattr(config, s) for s in ('semantic', 'features', 'keypoints')
        ):
            with self._cache_lock:
                self._prepared.clear()
        self._enforce_bounds()

    # -- contents ------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._keyframes)

    def __iter__(self) -> Iterator[StoredKeyframe]:
        return iter(list(self._keyframes.values()))

    def __getitem__(self, keyframe_id: int) -> StoredKeyframe:
        return self._keyframes[keyframe_id]

    @property
    def ids(self) -> list[int]:
        """Keyframe ids in insertion order."""
        return list(self._keyframes)

    @property
    def memory_bytes(self) -> int:
        """Memory of the keyframes' arrays (the bound of ``map.max_memory_mb``)."""
        return self._bytes

    @property
    def last(self) -> StoredKeyframe | None:
        """Return the keyframe added last, or None when empty."""
        return next(reversed(self._keyframes.values())) if self._keyframes else None

    def is_new_keyframe(self, T_map_sensor: np.ndarray) -> bool:
        """Whether a scan at this pose is far enough from the last keyframe to be added."""
        last = self.last
        if last is None:
            return True
        motion = invert_transform(last.T_map_keyframe) @ np.asarray(T_map_sensor)
        cfg = self.config.map
        return bool(
            np.linalg.norm(motion[:3, 3]) >= cfg.keyframe_distance
            or rotation_angle_deg(motion) >= cfg.keyframe_rotation
        )

    def add(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        T_map_keyframe: np.ndarray,
        stamp_ns: int = 0,
        *,
        prepared: PreparedScan | None = None,
        keyframe_id: int | None = None,
    ) -> StoredKeyframe:
        """
        Add a keyframe (points (N, 3) sensor frame, learning ids (N,), pose (4, 4)).

        ``prepared``: its prepared scan, if the caller has one (saves a preparation).
        ``keyframe_id``: keep a given id (a loaded map); by default the next free one.
        The bounds are enforced afterwards (the new keyframe is never the one dropped).
        """
        points = np.ascontiguousarray(np.asarray(points, dtype=np.float32).reshape(-1, 3))
        labels = np.ascontiguousarray(np.asarray(labels).reshape(-1).astype(np.uint32))
        if labels.shape[0] != points.shape[0]:
            raise ValueError(f'{points.shape[0]} points but {labels.shape[0]} labels')
        pose = np.asarray(T_map_keyframe, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError('T_map_keyframe must be a finite (4, 4) transform')
        new_id = self._next_id if keyframe_id is None else int(keyframe_id)
        if new_id in self._keyframes:
            raise ValueError(f'keyframe id {new_id} exists')
        self._next_id = max(self._next_id, new_id + 1)
        keyframe = StoredKeyframe(new_id, points, labels, pose.copy(), int(stamp_ns))
        self._keyframes[new_id] = keyframe
        self._bytes += keyframe.nbytes
        if prepared is not None:
            self._cache_prepared(new_id, prepared)
        self._index = None
        self._changed()
        self._enforce_bounds(keep=new_id)
        return keyframe

    def remove(self, keyframe_id: int) -> None:
        """Drop a keyframe and what is cached of it."""
        keyframe = self._keyframes.pop(keyframe_id)
        self._bytes -= keyframe.nbytes
        with self._cache_lock:
            self._prepared.pop(keyframe_id, None)
        self._index = None
        self._changed()

    def set_poses(self, poses: dict[int, np.ndarray]) -> None:
        """Move keyframes (``{id: T_map_keyframe}``, e.g. after a loop closure)."""
        for keyframe_id, pose in poses.items():
            if keyframe_id in self._keyframes:
                self._keyframes[keyframe_id].T_map_keyframe = np.asarray(
                    pose, dtype=np.float64
                ).copy()
        self._index = None  # positions changed
        self._changed()

    def poses(self) -> np.ndarray:
        """``T_map_keyframe`` (K, 4, 4) in insertion order."""
        if not self._keyframes:
            return np.zeros((0, 4, 4))
        return np.stack([k.T_map_keyframe for k in self._keyframes.values()])

    # -- derived data ----------------------------------------------------------------
    def descriptor(self, keyframe_id: int) -> PlaceDescriptor:
        """Return the keyframe's place descriptor, computed once per configuration."""
        keyframe = self._keyframes[keyframe_id]
        if keyframe.descriptor is None:
            keyframe.descriptor = self.describe(keyframe.points, keyframe.labels)
            self._bytes += keyframe.descriptor.nbytes
        return keyframe.descriptor

    def describe(self, points: np.ndarray, labels: np.ndarray) -> PlaceDescriptor:
        """Place descriptor of any scan (sensor frame, learning ids) with this configuration."""
        return describe(points, labels, self._channels, self.config.map)

    def place_index(self) -> tuple[PlaceIndex, list[int]]:
        """Return the place index of every keyframe and the keyframe id of each row."""
        with self._cache_lock:  # built once, also when a background preparation builds it
            if self._index is None:
                ids = self.ids
                descriptors = [self.descriptor(i) for i in ids]
                positions = np.array([self._keyframes[i].position for i in ids]).reshape(-1, 3)
                self._index, self._index_ids = PlaceIndex(descriptors, positions), ids
            return self._index, self._index_ids

    def prepared(self, keyframe_id: int, registration: object) -> PreparedScan:
        """Return the keyframe's prepared scan for ``registration`` (LRU-cached, lazy)."""
        with self._cache_lock:
            if keyframe_id in self._prepared:
                self._prepared.move_to_end(keyframe_id)
                return self._prepared[keyframe_id]
        keyframe = self._keyframes[keyframe_id]
        scan = registration.prepare(  # type: ignore[attr-defined]
            keyframe.points.astype(np.float64), keyframe.labels, lazy=True
        )
        self._cache_prepared(keyframe_id, scan)
        return scan

    def derived(self, key: Any, build: Callable[[], Any]) -> Any:
        """
        Return ``build()``, cached under ``key`` until the store changes (LRU).

        For data derived from several keyframes and their poses (the submap clouds of
        core/maps/submap_check.py): a keyframe added or removed, a pose moved or the
        configuration changed drops every entry. At most ``map.prepared_cache`` are kept.
        """
        with self._cache_lock:
            if key in self._derived:
                self._derived.move_to_end(key)
                return self._derived[key]
            generation = self._generation
        value = build()
        with self._cache_lock:
            if generation == self._generation:  # not made stale while it was built
                self._derived[key] = value
                while len(self._derived) > self.config.map.prepared_cache:
                    self._derived.popitem(last=False)
        return value

    def _changed(self) -> None:
        """Drop what :meth:`derived` cached (the keyframes, their poses or the config changed)."""
        with self._cache_lock:
            self._generation += 1
            self._derived.clear()

    def is_prepared(self, keyframe_id: int) -> bool:
        """Tell whether the keyframe's prepared scan is in the cache (not counted as a use)."""
        with self._cache_lock:
            return keyframe_id in self._prepared

    def prepare_ahead(self, registration: object, stop: Callable[[], bool] | None = None) -> int:
        """
        Prepare keyframes before a query needs them (``map.prepare_on_load``); return the count.

        Each keyframe not in the cache yet is prepared completely (keypoints, descriptors,
        Local-SS, landmarks, KD-tree) with the alignment cloud of the pair's fine
        alignment, in store order, until the cache holds ``map.prepared_cache`` scans.
        ``stop``: asked before each keyframe (e.g. the node shuts down). It stops by
        itself when the configuration changes (its scans would be stale).
        """
        config, done = self.config, 0
        for keyframe_id in self.ids:
            with self._cache_lock:
                full = len(self._prepared) >= config.map.prepared_cache
                if full or self._config is not config:
                    break
                if keyframe_id in self._prepared:
                    continue
            if stop is not None and stop():
                break
            keyframe = self._keyframes.get(keyframe_id)
            if keyframe is None:  # dropped meanwhile
                continue
            scan = registration.prepare(  # type: ignore[attr-defined]
                keyframe.points.astype(np.float64), keyframe.labels
            )
            alignment_cloud(scan, config.fine, pair=True)
            with self._cache_lock:
                if self._config is not config or keyframe_id not in self._keyframes:
                    break
                if keyframe_id not in self._prepared:  # a query may have prepared it
                    self._cache_prepared(keyframe_id, scan, use=False)
                    done += 1
        return done

    def _cache_prepared(self, keyframe_id: int, scan: PreparedScan, use: bool = True) -> None:
        """Cache a prepared scan; ``use`` False: the least recently used end (ahead of use)."""
        with self._cache_lock:
            self._prepared[keyframe_id] = scan
            self._prepared.move_to_end(keyframe_id, last=use)
            while len(self._prepared) > self.config.map.prepared_cache:
                self._prepared.popitem(last=False)

    # -- bounds ----------------------------------------------------------------------
    def _enforce_bounds(self, keep: int | None = None) -> None:
        """Drop the most redundant keyframes until count and memory are within bounds."""
        cfg = self.config.map
        limit = cfg.max_memory_mb * 1e6
        while len(self._keyframes) > 1 and (
            len(self._keyframes) > cfg.max_keyframes or self._bytes > limit
        ):
            self.remove(self._most_redundant(keep))
            self.dropped += 1

    def _most_redundant(self, keep: int | None) -> int:
        """Id of the keyframe nearest to another one (never ``keep``)."""
        ids = [i for i in self._keyframes if i != keep]
        positions = np.array([self._keyframes[i].position for i in self._keyframes])
        all_ids = list(self._keyframes)
        distance, _ = cKDTree(positions).query(positions, k=2)
        gap = dict(zip(all_ids, distance[:, 1], strict=False))
        return min(ids, key=lambda i: gap[i])
