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
Semantic label maps: class names <-> learning ids <-> raw ids.

Configuration speaks in class names. Scans arrive either with SemanticKITTI
learning ids (0-19) or raw ids (10 car, 40 road, 252 moving-car, ...; the
instance id in the upper 16 bits of a uint32). Everything downstream of
:meth:`LabelMap.to_learning` works on learning ids.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mlsemreg_ros.core.config import ConfigError
from mlsemreg_ros.core.resources import share_file
import numpy as np
import yaml

SCHEMES = ('auto', 'learning', 'raw')
_RAW_MASK = 0xFFFF


class LabelError(ValueError):
    """Labels cannot be interpreted (wrong values for the scheme, NaN, ...)."""


@dataclass(frozen=True)
class LabelMap:
    """Class names indexed by learning id, plus the raw -> learning lookup table."""

    name: str
    names: tuple[str, ...]
    raw_lut: np.ndarray  # (65536,) int32: raw semantic id -> learning id
    learning_to_raw_ids: np.ndarray  # (num_classes,) int64: canonical raw id per class

    @classmethod
    def load(cls, path: str | Path | None = None) -> LabelMap:
        """Read a label-map YAML (default: ``config/labels/semantic_kitti.yaml``)."""
        path = Path(path) if path is not None else share_file('config/labels/semantic_kitti.yaml')
        data = yaml.safe_load(path.read_text())
        names = tuple(str(n) for n in data['learning'])
        lut = np.zeros(_RAW_MASK + 1, dtype=np.int32)
        for raw, learning in data['raw_to_learning'].items():
            if not 0 <= int(learning) < len(names):
                raise ConfigError(f'{path}: raw id {raw} maps to unknown learning id {learning}')
            lut[int(raw)] = int(learning)
        to_raw = np.zeros(len(names), dtype=np.int64)
        for learning, raw in data.get('learning_to_raw', {}).items():
            to_raw[int(learning)] = int(raw)
        return cls(str(data.get('name', path.stem)), names, lut, to_raw)

    @property
    def num_classes(self) -> int:
        """Return the number of learning classes (including ``unlabeled``)."""
        return len(self.names)

    def id_of(self, name: str) -> int:
        """Learning id of a class name; ConfigError naming the known classes otherwise."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(
                f'unknown class {name!r}; known classes: {", ".join(self.names)}') from None

    def ids_of(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Learning ids of several class names."""
        return np.array([self.id_of(n) for n in names], dtype=np.int64)

    def detect_scheme(self, labels: np.ndarray) -> str:
        """
        ``'raw'`` if any value exceeds the largest learning id, else ``'learning'``.

        A raw scan that only holds raw ids <= 19 (unlabeled, car, bicycle, truck)
        is read as learning ids; set the scheme explicitly for such data.
        """
        if labels.size == 0:
            return 'learning'
        return 'raw' if int(labels.max()) >= self.num_classes else 'learning'

    def to_learning(self, labels: np.ndarray, scheme: str = 'auto') -> np.ndarray:
        """
        Map labels of any integer or float dtype to learning ids (int32).

        Raw ids lose their instance bits (upper 16) before the lookup; unknown raw
        ids become 0 (unlabeled). Learning ids outside ``[0, num_classes)`` and
        non-finite or non-integral floats raise :class:`LabelError`.
        """
        if scheme not in SCHEMES:
            raise LabelError(f'unknown label scheme {scheme!r}; use one of {SCHEMES}')
        values = np.asarray(labels).reshape(-1)
        if values.dtype.kind == 'f':
            if not np.all(np.isfinite(values)):
                raise LabelError('labels contain NaN or inf')
            if np.any(values != np.round(values)):
                raise LabelError('float labels must hold integral values')
            values = values.astype(np.int64)
        elif values.dtype.kind not in 'iub':
            raise LabelError(f'unsupported label dtype {values.dtype}')
        values = values.astype(np.int64, copy=False)
        if values.size and values.min() < 0:
            # A signed 32-bit raw label with a large instance id is negative.
            values = values & 0xFFFFFFFF
        if scheme == 'auto':
            scheme = self.detect_scheme(values & _RAW_MASK if values.size and
                                        values.max() > _RAW_MASK else values)
        if scheme == 'raw':
            return self.raw_lut[values & _RAW_MASK]
        if values.size and values.max() >= self.num_classes:
            raise LabelError(
                f'learning ids must lie in [0, {self.num_classes - 1}], got max {values.max()}')
        return values.astype(np.int32)

    def to_raw(self, learning: np.ndarray, instance: np.ndarray | None = None) -> np.ndarray:
        """Canonical raw ids (uint32) of learning ids, optionally with instance ids."""
        raw = self.learning_to_raw_ids[np.asarray(learning, dtype=np.int64)].astype(np.uint32)
        if instance is not None:
            raw |= (np.asarray(instance, dtype=np.uint32) & _RAW_MASK) << np.uint32(16)
        return raw
