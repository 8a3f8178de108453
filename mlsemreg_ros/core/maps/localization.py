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
Map-relative localization around the odometry: ``T_map_odom`` (docs/maps.md).

:class:`MapLocalization` runs after every odometry step, in one of two modes:

- **localization** (a map was loaded, ``map.load_path``): unlocalized at first, every scan
  is relocalized against the map (:mod:`mlsemreg_ros.core.maps.relocalization`) until one is
  accepted, which gives ``T_map_odom = T_map_sensor @ inv(T_odom_sensor)``. Localized, the
  scan is registered onto the map keyframes near its predicted map pose every
  ``map.track_distance`` metres; an accepted registration within
  ``map.loop_search_radius`` of the prediction corrects ``T_map_odom``. The map stays as it
  was loaded.
- **mapping** (no map): accepted scans feed a :class:`~mlsemreg_ros.core.maps.mapping.Mapper`
  (keyframes, loop closures, pose graph); ``T_map_odom`` is the mapper's (identity until
  a loop closes).

In both modes a lost odometry (``map.relocalize_after_failures`` rejected scans in a row)
relocalizes the scan against the keyframes (the map, or its own store while mapping); an
accepted relocalization restarts the odometry on that scan at
``T_odom_sensor = inv(T_map_odom) @ T_map_sensor`` instead of waiting for
``keyframe.max_failures`` rejections.
"""

from __future__ import annotations

from dataclasses import dataclass
import threading
from typing import Any

from mlsemreg_ros.core.features.deskew import time_span_refusal
from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
from mlsemreg_ros.core.maps.mapping import Mapper
from mlsemreg_ros.core.maps.relocalization import Relocalization, Relocalizer
from mlsemreg_ros.core.maps.seed import PoseSeed
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np


def awaits_deskew(step: Any, point_times: np.ndarray | None, config: Any) -> bool:
    """
    Whether a scan with per-point times was left skewed by the odometry (its first scans).

    The odometry deskews a scan only once it knows the motion (``preprocess.deskew``); its
    first scans keep the skew of the sweep, up to the distance driven in one period. A
    relocalization or a keyframe of such a scan is off by about half that (docs/maps.md:
    1 m at 10 m/s on the simulated field drives), so they wait for a deskewed scan. With
    ``preprocess.deskew`` off, or scans without usable times, nothing waits.
    """
    if point_times is None or config.preprocess.deskew == 'off':
        return False
    if getattr(step, 'deskewed', False):
        return False
    return not time_span_refusal(point_times, len(point_times))  # times that could deskew


@dataclass
class LocalizationUpdate:
    """What one scan did to the map-relative state."""

    localized: bool
    T_map_odom: np.ndarray | None  # None while unlocalized
    changed: bool  # T_map_odom was set or corrected by this scan
    event: str  # '', relocalized, tracked, loop, recovered, refused
    message: str = ''
    relocalization: Relocalization | None = None
    restarted: Any = None  # the odometry step of a restart on this scan (recovered)


class MapLocalization:
    """``T_map_odom`` from a loaded map (localization) or from mapping (module docstring)."""

    def __init__(
        self,
        registration: Registration,
        store: KeyframeStore | None = None,
        frame_id: str = 'map',
    ) -> None:
        """Localize against ``store`` (a loaded map); without one, map as we go."""
        self.registration = registration
        self.frame_id = frame_id
        self.mode = 'localization' if store is not None else 'mapping'
        self.mapper = Mapper(registration) if store is None else None
        self.store = store if store is not None else self.mapper.store
        self.relocalizer = Relocalizer(registration, self.store)
        self.lock = threading.Lock()  # guards the store against a concurrent save
        self.localized = self.mode == 'mapping'
        self._T_map_odom = np.eye(4)
        self._failures = 0
        self._travel_since_track = 0.0
        self._last_position: np.ndarray | None = None
        self._relocalize_requested = False
        self._seed: PoseSeed | None = None  # relocalize the next scan around it

    @property
    def T_map_odom(self) -> np.ndarray | None:
        """Return the odom frame in the map (None while unlocalized)."""
        if not self.localized:
            return None
        if self.mapper is not None:
            return self.mapper.T_map_odom.copy()
        return self._T_map_odom.copy()

    def prepare_map(self) -> None:
        """
        With a loaded map and ``map.prepare_on_load``: prepare it for relocalization now.

        On a background thread (:meth:`Relocalizer.prepare_map`): the place index and up to
        ``map.prepared_cache`` keyframes, so that the first relocalizations do not pay for
        them. :meth:`close` stops it.
        """
        if self.mode == 'localization' and self.store.config.map.prepare_on_load:
            self.relocalizer.prepare_map(background=True)

    def close(self) -> None:
        """Stop a background preparation (:meth:`prepare_map`)."""
        self.relocalizer.stop_preparing()

    def request_relocalization(self) -> None:
        """Relocalize the next scan whatever the state (the relocalize service)."""
        self._relocalize_requested = True

    def seed(self, seed: PoseSeed) -> str:
        """Relocalize the next scan around ``seed`` (core/maps/seed.py); '' or why not."""
        if self.mode != 'localization':
            return 'no map loaded: a seed needs a map'
        self._seed, self._relocalize_requested = seed, True
        return ''

    def force(self, T_map_sensor: np.ndarray, T_odom_sensor: np.ndarray) -> None:
        """Take the sensor at ``T_map_sensor`` now (odometry at ``T_odom_sensor``), unchecked."""
        with self.lock:
            self._set_T_map_odom(T_map_sensor @ invert_transform(T_odom_sensor))
            self._last_position = T_odom_sensor[:3, 3].copy()

    def reset(self) -> None:
        """
        Forget ``T_map_odom``: the odometry restarted at identity.

        Localization: unlocalized until a scan relocalizes. Mapping: a new, empty map.
        """
        if self.mode == 'mapping':  # a new map from the restarted odometry
            self.mapper = Mapper(self.registration)
            self.store = self.mapper.store
            self.relocalizer = Relocalizer(self.registration, self.store)
        else:
            self.localized = False
        self._failures = 0
        self._last_position = None

    def update(
        self,
        odometry: Any,
        step: Any,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None = None,
    ) -> LocalizationUpdate:
        """
        Take one odometry step (``odometry``: the :class:`Odometry` that made it).

        ``point_times``: the scan's per-point times, if it has them; a timed scan that the
        odometry could not deskew is neither relocalized nor mapped (:func:`awaits_deskew`).
        """
        with self.lock:
            return self._update(odometry, step, points, labels, point_times)

    def _update(
        self,
        odometry: Any,
        step: Any,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None = None,
    ) -> LocalizationUpdate:
        cfg = self.store.config.map
        self._failures = 0 if step.accepted else self._failures + 1
        if awaits_deskew(step, point_times, self.store.config):
            return self._state('', 'scan not deskewed (no motion yet): not relocalized or mapped')
        lost = (
            cfg.relocalize_after_failures > 0
            and self._failures >= cfg.relocalize_after_failures
            and len(self.store) > 0
        )
        if lost:
            return self._recover(odometry, step, points, labels)
        if not step.accepted:
            return self._state('', 'scan rejected by the odometry')
        if not self.localized or self._relocalize_requested:
            self._relocalize_requested = False
            if len(self.store) > 0 or self.mode == 'localization':
                return self._relocalize(step, points, labels)
            self.localized = True  # mapping from scratch: the odom frame is the map frame
        if self.mode == 'mapping':
            mapped = self.mapper.add(
                points, labels, step.pose, step.stamp_ns, prepared=step.prepared
            )
            if mapped.loop is not None:
                loop = mapped.loop
                return self._state(
                    'loop',
                    f'loop closed: keyframe {loop.current} onto {loop.match} (moved '
                    f'{loop.correction_m:.2f} m)',
                    changed=True,
                )
            return self._state('', '')
        return self._track(step, points, labels)

    def _relocalize(self, step: Any, points: np.ndarray, labels: np.ndarray) -> LocalizationUpdate:
        """Find ``T_map_odom`` by relocalizing the scan against the keyframes (or a seed's)."""
        seed, self._seed = self._seed, None
        allowed = seed.candidates(self.store) if seed is not None else None
        if allowed is not None and not allowed:
            return self._state('refused', 'seed refused: no map keyframe near the seed')
        found = self.relocalizer.relocalize(
            points, labels, prepared=step.prepared, allowed=allowed
        )
        if not found.found:
            why = _refusal(found)
            return self._state(
                'refused', f'seed refused: {why}' if seed else why, relocalization=found
            )
        outside = seed.refusal(found.T_map_sensor) if seed is not None else ''
        if outside:
            return self._state('refused', f'seed refused: {outside}', relocalization=found)
        self._set_T_map_odom(found.T_map_sensor @ invert_transform(step.pose))
        self._last_position = step.pose[:3, 3].copy()
        around = ' around the seed' if seed is not None else ''
        return self._state(
            'relocalized',
            f'relocalized{around} onto keyframe {found.keyframe_id} after '
            f'{len(found.trials)} registrations',
            changed=True,
            relocalization=found,
        )

    def _set_T_map_odom(self, T_map_odom: np.ndarray) -> None:
        self.localized, self._travel_since_track = True, 0.0
        if self.mapper is not None:
            self.mapper.rebase(T_map_odom)
        else:
            self._T_map_odom = T_map_odom.copy()

    def _track(self, step: Any, points: np.ndarray, labels: np.ndarray) -> LocalizationUpdate:
        cfg = self.store.config.map
        position = step.pose[:3, 3]
        if self._last_position is not None:
            self._travel_since_track += float(np.linalg.norm(position - self._last_position))
        self._last_position = position.copy()
        if cfg.track_distance <= 0 or self._travel_since_track < cfg.track_distance:
            return self._state('', '')
        self._travel_since_track = 0.0
        predicted = self._T_map_odom @ step.pose
        radius = cfg.loop_search_radius
        nearby = {
            k.keyframe_id
            for k in self.store
            if radius <= 0 or np.linalg.norm(k.position - predicted[:3, 3]) <= radius
        }
        if not nearby:
            return self._state('', 'no map keyframe near the predicted pose')
        found = self.relocalizer.relocalize(points, labels, prepared=step.prepared, allowed=nearby)
        if not found.found:
            return self._state('', _refusal(found), relocalization=found)
        moved = float(np.linalg.norm(found.T_map_sensor[:3, 3] - predicted[:3, 3]))
        if radius > 0 and moved > radius:
            return self._state('', f'map registration {moved:.1f} m from the prediction: ignored')
        self._T_map_odom = found.T_map_sensor @ invert_transform(step.pose)
        return self._state(
            'tracked',
            f'map -> odom corrected by {moved:.2f} m',
            changed=True,
            relocalization=found,
        )

    def _recover(
        self, odometry: Any, step: Any, points: np.ndarray, labels: np.ndarray
    ) -> LocalizationUpdate:
        """Relocalize a lost odometry's scan; restart the odometry on it if accepted."""
        found = self.relocalizer.relocalize(points, labels, prepared=step.prepared)
        if not found.found:
            return self._state('refused', f'lost: {_refusal(found)}', relocalization=found)
        T_map_odom = self.mapper.T_map_odom if self.mapper is not None else self._T_map_odom
        if not self.localized:  # localization mode, never localized: odom follows the map
            T_map_odom = found.T_map_sensor @ invert_transform(step.pose)
            self._T_map_odom, self.localized = T_map_odom, True
        T_odom_sensor = invert_transform(T_map_odom) @ found.T_map_sensor
        odometry.reset()
        odometry.pose = T_odom_sensor
        restarted = odometry.process(points, labels, step.stamp_ns)
        self._failures = 0
        self._last_position = T_odom_sensor[:3, 3].copy()
        return self._state(
            'recovered',
            f'odometry lost: relocalized onto keyframe {found.keyframe_id} and restarted there',
            changed=True,
            relocalization=found,
            restarted=restarted,
        )

    def _state(
        self,
        event: str,
        message: str,
        *,
        changed: bool = False,
        relocalization: Relocalization | None = None,
        restarted: Any = None,
    ) -> LocalizationUpdate:
        return LocalizationUpdate(
            self.localized, self.T_map_odom, changed, event, message, relocalization, restarted
        )

    def save(self, path: Any) -> Any:
        """Write the map (loaded, or mapped so far with its corrected poses) to ``path``."""
        from mlsemreg_ros.core.maps.map_io import save_map

        with self.lock:
            return save_map(path, self.store, self.frame_id, self.registration.config)


def _refusal(found: Relocalization) -> str:
    if not found.trials:
        return 'no candidate keyframe'
    last = found.trials[-1].message or 'refused'
    return f'{len(found.trials)} candidates refused (last: {last})'
