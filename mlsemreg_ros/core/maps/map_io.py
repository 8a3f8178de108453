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
Map folders: save and load a keyframe map (the format is documented in docs/maps.md).

::

    MAP/
      map.yaml              format: mlsemreg-map/1, frame_id, keyframes, [registration]
      keyframes/000000.npz  points (N, 3) float32 sensor frame, labels (N,) uint32,
                            T_map_keyframe (4, 4) float64, stamp_ns int64
      poses.txt             TUM lines 'stamp tx ty tz qx qy qz qw' (for viewing)

A keyframe file may also hold ``intensity`` (N,) float32 (imported point maps keep it for
``mlsemreg map export``).

``keyframes`` is the number of keyframe files (``000000.npz`` ... in order) or a list of
their names relative to ``keyframes/``. Labels are learning or raw SemanticKITTI ids, told
apart per keyframe like the node's input (:meth:`LabelMap.convert` with ``auto``).
Every problem of a folder is a :class:`MapError` naming the file and what is wrong.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import shutil
from typing import Any

from mlsemreg_ros.core.config import ConfigError, load_yaml, RegistrationConfig
from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
from mlsemreg_ros.core.matching.labels import LabelMap
import numpy as np
import yaml

#: The value of ``format`` in ``map.yaml``.
MAP_FORMAT = 'mlsemreg-map/1'
MAP_FILE = 'map.yaml'
KEYFRAME_DIR = 'keyframes'
POSES_FILE = 'poses.txt'
KEYFRAME_KEYS = ('points', 'labels', 'T_map_keyframe', 'stamp_ns')


class MapError(ValueError):
    """A map folder cannot be read or written; the message names the file and the problem."""


@dataclass
class MapKeyframe:
    """One keyframe as stored in a map folder."""

    points: np.ndarray  # (N, 3) float32
    labels: np.ndarray  # (N,) uint32
    T_map_keyframe: np.ndarray  # (4, 4) float64
    stamp_ns: int
    intensity: np.ndarray | None = None  # (N,) float32, optional (imported point maps)


@dataclass
class MapData:
    """The contents of a map folder."""

    frame_id: str
    keyframes: list[MapKeyframe]
    config: RegistrationConfig | None  # the registration config stored with it, if any

    def store(
        self, config: RegistrationConfig | None = None, label_map: LabelMap | None = None
    ) -> KeyframeStore:
        """
        Return a keyframe store of these keyframes, labels converted to learning ids.

        ``config``: the store's config (default: the map's own, else the defaults). The
        store's bounds apply: a map larger than ``map.max_keyframes`` loses keyframes.
        """
        label_map = label_map if label_map is not None else LabelMap.load()
        cfg = config or self.config or RegistrationConfig()
        store = KeyframeStore(cfg, label_map)
        scheme = cfg.semantic.label_scheme
        for keyframe in self.keyframes:
            ids = label_map.convert(keyframe.labels, scheme).ids
            store.add(keyframe.points, ids, keyframe.T_map_keyframe, keyframe.stamp_ns)
        return store


def save_map(
    path: str | Path,
    store: KeyframeStore | list[MapKeyframe],
    frame_id: str = 'map',
    config: RegistrationConfig | None = None,
    overwrite: bool = True,
) -> Path:
    """
    Write ``store`` as a map folder at ``path`` (keyframes renumbered 0.. in store order).

    ``store``: a keyframe store, or a list of :class:`MapKeyframe` (an imported map).
    ``config``: the registration config written into ``map.yaml`` (default: the store's,
    else the defaults).
    The folder is written next to ``path`` first and moved into place, so a failed save
    leaves an existing map as it was.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise MapError(f'{path} exists')
    if path.exists() and not (path / MAP_FILE).exists():
        raise MapError(f'{path} exists and is not a map folder (no {MAP_FILE}); not replaced')
    staging = path.with_name(path.name + '.saving')
    shutil.rmtree(staging, ignore_errors=True)
    try:
        (staging / KEYFRAME_DIR).mkdir(parents=True)
        keyframes = list(store)
        for number, keyframe in enumerate(keyframes):
            intensity = getattr(keyframe, 'intensity', None)
            extra = {} if intensity is None else {'intensity': intensity.astype(np.float32)}
            np.savez(
                staging / KEYFRAME_DIR / f'{number:06d}.npz',
                points=keyframe.points.astype(np.float32),
                labels=keyframe.labels.astype(np.uint32),
                T_map_keyframe=keyframe.T_map_keyframe.astype(np.float64),
                stamp_ns=np.int64(keyframe.stamp_ns),
                **extra,
            )
        header: dict[str, Any] = {
            'format': MAP_FORMAT,
            'frame_id': frame_id,
            'keyframes': len(keyframes),
            'registration': (
                config or getattr(store, 'config', None) or RegistrationConfig()
            ).to_dict(),
        }
        (staging / MAP_FILE).write_text(yaml.safe_dump(header, sort_keys=False))
        _write_tum(staging / POSES_FILE, keyframes)
        if path.exists():
            shutil.rmtree(path)
        staging.rename(path)
    except OSError as error:
        shutil.rmtree(staging, ignore_errors=True)
        raise MapError(f'cannot write the map {path}: {error}') from None
    return path


def _write_tum(path: Path, keyframes: list) -> None:
    from mlsemreg_ros.codec.pose_files import write_tum_poses

    poses = np.array([k.T_map_keyframe for k in keyframes]).reshape(-1, 4, 4)
    stamps = np.array([k.stamp_ns for k in keyframes], dtype=np.int64)
    write_tum_poses(path, stamps, poses)


def load_map(path: str | Path) -> MapData:
    """Read and validate a map folder (MapError with the file and the reason otherwise)."""
    path = Path(path)
    header_file = path / MAP_FILE
    if not header_file.is_file():
        raise MapError(f'{path} is not a map folder: no {MAP_FILE}')
    try:
        header = load_yaml(header_file.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise MapError(f'{header_file}: cannot parse: {error}') from None
    if not isinstance(header, dict):
        raise MapError(f'{header_file}: must be a mapping with format, frame_id, keyframes')
    if header.get('format') != MAP_FORMAT:
        raise MapError(
            f'{header_file}: format is {header.get("format")!r}, expected {MAP_FORMAT!r}'
        )
    frame_id = header.get('frame_id', 'map')
    if not isinstance(frame_id, str) or not frame_id or frame_id.startswith('/'):
        raise MapError(f'{header_file}: frame_id must be a tf2 frame name, got {frame_id!r}')
    names = _keyframe_names(header_file, header.get('keyframes'))
    config = None
    if header.get('registration') is not None:
        try:
            config = RegistrationConfig.from_dict(header['registration'])
        except ConfigError as error:
            raise MapError(f'{header_file}: registration: {error}') from None
    keyframes = [_read_keyframe(path / KEYFRAME_DIR / name) for name in names]
    return MapData(frame_id, keyframes, config)


def _keyframe_names(header_file: Path, keyframes: Any) -> list[str]:
    if isinstance(keyframes, bool) or not isinstance(keyframes, int | list):
        raise MapError(
            f'{header_file}: keyframes must be a count or a list of file names, got {keyframes!r}'
        )
    if isinstance(keyframes, int):
        if keyframes < 0:
            raise MapError(f'{header_file}: keyframes must not be negative, got {keyframes}')
        return [f'{i:06d}.npz' for i in range(keyframes)]
    if not all(isinstance(n, str) for n in keyframes):
        raise MapError(f'{header_file}: keyframes: every entry must be a file name')
    return list(keyframes)


def _read_keyframe(file: Path) -> MapKeyframe:
    if not file.is_file():
        raise MapError(f'{file}: missing (listed by {MAP_FILE})')
    try:
        with np.load(file, allow_pickle=False) as data:
            missing = [k for k in KEYFRAME_KEYS if k not in data.files]
            if missing:
                raise MapError(f'{file}: missing {missing}; has {sorted(data.files)}')
            points, labels = np.asarray(data['points']), np.asarray(data['labels'])
            pose, stamp = np.asarray(data['T_map_keyframe']), np.asarray(data['stamp_ns'])
            intensity = np.asarray(data['intensity']) if 'intensity' in data.files else None
    except (OSError, ValueError) as error:
        if isinstance(error, MapError):
            raise
        raise MapError(f'{file}: cannot read: {error}') from None
    if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.floating):
        raise MapError(f'{file}: points must be (N, 3) floats, got {points.shape} {points.dtype}')
    if not np.all(np.isfinite(points)):
        raise MapError(f'{file}: points hold non-finite values')
    if labels.shape != (points.shape[0],) or not np.issubdtype(labels.dtype, np.integer):
        raise MapError(
            f'{file}: labels must be ({points.shape[0]},) integers, got '
            f'{labels.shape} {labels.dtype}'
        )
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise MapError(f'{file}: T_map_keyframe must be a finite (4, 4) matrix')
    rotation = pose[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-4) or not np.allclose(
        pose[3], [0, 0, 0, 1]
    ):
        raise MapError(f'{file}: T_map_keyframe is not a rigid transform')
    if stamp.shape != () or not np.issubdtype(stamp.dtype, np.integer):
        raise MapError(f'{file}: stamp_ns must be one integer, got {stamp.shape} {stamp.dtype}')
    if intensity is not None and intensity.shape != (points.shape[0],):
        raise MapError(f'{file}: intensity must be ({points.shape[0]},), got {intensity.shape}')
    return MapKeyframe(
        points.astype(np.float32),
        labels.astype(np.uint32),
        pose.astype(np.float64),
        int(stamp),
        None if intensity is None else intensity.astype(np.float32),
    )


def load_store(
    path: str | Path, config: RegistrationConfig | None = None, label_map: LabelMap | None = None
) -> tuple[KeyframeStore, MapData]:
    """Load a map folder into a keyframe store (:meth:`MapData.store`)."""
    data = load_map(path)
    return data.store(config, label_map), data
