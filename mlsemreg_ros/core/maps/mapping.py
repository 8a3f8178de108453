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
Mapping: keyframes from accepted odometry poses, loop closures, the pose graph (docs/maps.md).

:meth:`Mapper.add` takes every accepted scan with its odometry pose ``T_odom_sensor``.
A scan far enough from the last keyframe (``map.keyframe_distance`` /
``map.keyframe_rotation``) becomes a keyframe of the store at
``T_map_sensor = T_map_odom @ T_odom_sensor``, a node of the pose graph with the odometry
since the previous keyframe as its edge. With ``map.loop_closure``:

1. candidates are the keyframes the trajectory left at least ``map.loop_min_travel``
   metres ago, within ``map.loop_search_radius`` of the current pose;
2. place recognition ranks them (:mod:`mlsemreg_ros.core.maps.place_recognition`); at most
   ``map.loop_candidates`` with a scan context similarity of at least
   ``map.loop_min_similarity`` are registered onto (ML-SemReg, no initial guess);
3. a registration the confidence rule accepts, whose pose lies within
   ``map.loop_search_radius`` of the drifting one, is refined against a submap of the
   matched keyframe and its neighbours (``map.loop_refine``,
   :mod:`mlsemreg_ros.core.maps.submap_check`); if the refinement agrees, its pose
   becomes a loop edge; GTSAM optimizes the
   graph, the store's keyframes move to the optimized poses and ``T_map_odom`` is
   updated so that later poses continue from the corrected one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore, StoredKeyframe
from mlsemreg_ros.core.maps.pose_graph import PoseGraph
from mlsemreg_ros.core.maps.relocalization import Relocalizer
from mlsemreg_ros.core.maps.submap_check import refine_on_submap, static_points, SubmapCheck
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np


@dataclass
class LoopClosure:
    """A loop edge the mapper added (keyframe ``match`` seen again by ``current``)."""

    current: int
    match: int
    T_match_current: np.ndarray
    correction_m: float  # how far the loop moved the current keyframe
    check: SubmapCheck | None = None  # the submap refinement (map.loop_refine)


@dataclass
class MapperStep:
    """What one accepted scan did to the map."""

    keyframe: StoredKeyframe | None = None  # the new keyframe, if the scan became one
    loop: LoopClosure | None = None
    tried: list[int] = field(default_factory=list)  # loop candidates registered onto


class Mapper:
    """Builds a keyframe map from accepted odometry poses, closing loops (module docstring)."""

    def __init__(self, registration: Registration, store: KeyframeStore | None = None) -> None:
        """Map into ``store`` (default: a new, empty one) with ``registration``."""
        self.registration = registration
        self.store = store if store is not None else KeyframeStore(registration.config)
        self.graph = PoseGraph(self.store.config.map)
        self.relocalizer = Relocalizer(registration, self.store)
        self.T_map_odom = np.eye(4)
        self.loops: list[LoopClosure] = []
        self.refused: list[LoopClosure] = []  # accepted registrations the refinement refused
        self._odom: dict[int, np.ndarray] = {}  # T_odom_keyframe of every keyframe
        self._travel: dict[int, float] = {}  # distance travelled when it was added
        self._travelled = 0.0
        self._last_odom: np.ndarray | None = None

    def add(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        T_odom_sensor: np.ndarray,
        stamp_ns: int = 0,
        prepared: PreparedScan | None = None,
    ) -> MapperStep:
        """Take an accepted scan (the scan as prepared, if given, saves a preparation)."""
        T_odom_sensor = np.asarray(T_odom_sensor, dtype=np.float64)
        if self._last_odom is not None:
            self._travelled += float(np.linalg.norm(T_odom_sensor[:3, 3] - self._last_odom[:3, 3]))
        self._last_odom = T_odom_sensor
        T_map_sensor = self.T_map_odom @ T_odom_sensor
        if not self.store.is_new_keyframe(T_map_sensor):
            return MapperStep()
        if prepared is None:
            prepared = self.registration.prepare(points, labels, lazy=True)
        previous = self.store.last
        keyframe = self.store.add(
            prepared.points, prepared.labels, T_map_sensor, stamp_ns, prepared=prepared
        )
        relative = None  # the odometry edge, from the map poses (T_map_odom is rigid)
        if previous is not None:
            relative = invert_transform(previous.T_map_keyframe) @ T_map_sensor
        self.graph.add_keyframe(keyframe.keyframe_id, T_map_sensor, relative)
        self._odom[keyframe.keyframe_id] = T_odom_sensor.copy()
        self._travel[keyframe.keyframe_id] = self._travelled
        step = MapperStep(keyframe)
        if self.store.config.map.loop_closure:
            self._close_loop(keyframe, prepared, step)
        return step

    def _close_loop(
        self, keyframe: StoredKeyframe, prepared: PreparedScan, step: MapperStep
    ) -> None:
        cfg = self.store.config.map
        here = keyframe.position
        allowed = {
            k.keyframe_id
            for k in self.store
            if k.keyframe_id != keyframe.keyframe_id
            and self._travelled - self._travel.get(k.keyframe_id, self._travelled)
            >= cfg.loop_min_travel
            and (
                cfg.loop_search_radius <= 0
                or np.linalg.norm(k.position - here) <= cfg.loop_search_radius
            )
        }
        if not allowed:
            return
        index, ids = self.store.place_index()
        mask = np.array([i in allowed for i in ids], dtype=bool)
        query = self.store.describe(prepared.points, prepared.labels)
        shortlist = [
            c for c in index.shortlist(query, cfg, mask) if c.similarity >= cfg.loop_min_similarity
        ][: cfg.loop_candidates]
        for candidate in shortlist:
            match = ids[candidate.index]
            step.tried.append(match)
            target = self.store.prepared(match, self.registration)
            result = self.registration.register(prepared, target)
            if not (result.success and np.all(np.isfinite(result.transform))):
                continue
            T_match_current = result.transform
            T_map_current = self.store[match].T_map_keyframe @ T_match_current
            moved = float(np.linalg.norm(T_map_current[:3, 3] - here))
            if cfg.loop_search_radius > 0 and moved > cfg.loop_search_radius:
                continue
            check = None
            if cfg.loop_refine:
                check = refine_on_submap(
                    self.store,
                    match,
                    static_points(prepared),
                    T_match_current,
                    allowed,
                    cfg,
                    self.store.config.fine,
                )
                if not check.accepted:
                    self.refused.append(
                        LoopClosure(
                            keyframe.keyframe_id, match, T_match_current.copy(), moved, check
                        )
                    )
                    continue
                T_match_current = check.T_match_current
            self.graph.add_loop(match, keyframe.keyframe_id, T_match_current)
            optimized = self.graph.optimize()
            self.store.set_poses(optimized)
            self.T_map_odom = optimized[keyframe.keyframe_id] @ invert_transform(
                self._odom[keyframe.keyframe_id]
            )
            loop = LoopClosure(keyframe.keyframe_id, match, T_match_current.copy(), moved, check)
            self.loops.append(loop)
            step.loop = loop
            return

    def rebase(self, T_map_odom: np.ndarray) -> None:
        """
        Continue in a new odom frame whose place in the map is ``T_map_odom``.

        (Found by relocalizing against the store; the next keyframe's edge joins the map
        poses, so the graph stays connected.)
        """
        self.T_map_odom = np.asarray(T_map_odom, dtype=np.float64).copy()
        self._last_odom = None

    def keyframe_odometry(self) -> dict[int, np.ndarray]:
        """``T_odom_keyframe`` of every keyframe (the poses before any loop closure)."""
        return dict(self._odom)
