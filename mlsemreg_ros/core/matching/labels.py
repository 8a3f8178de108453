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
:meth:`LabelMap.convert` (and :meth:`LabelMap.to_learning`) works on learning ids.

Input rules (issue 11, "input hygiene"):

- Every label is read as a **uint32 bit pattern**: integer values of any width
  as their 32-bit two's complement (int32 -2**31 = ``0x80000000``: instance
  bits set, class 0; int8/int16 values are sign-extended first, so -1 is
  ``0xFFFFFFFF``, never a valid id), integral floats by value. Values that do
  not fit 32 bits (int64/uint64/float beyond ``[-2**31, 2**32)``) are valid in
  no scheme. NaN/inf and non-integral floats raise :class:`LabelError`.
- A value is a valid **learning id** if its pattern is ``0 .. num_classes - 1``
  (no instance bits) and a valid **raw id** if its lower 16 bits are a key of
  the raw -> learning table (any instance bits).
- ``auto`` reads a scan as raw ids when the share of its values that are valid
  raw ids exceeds the share of valid learning ids by at least
  :data:`AUTO_RAW_MARGIN`, both shares taken over the non-zero values (0 is
  unlabeled in both schemes and says nothing); otherwise as learning ids. Stray
  values cannot flip a scan: it takes a quarter of its labeled values.
- Values outside the chosen scheme become 0 (``unlabeled``) and are counted
  in :attr:`LabelConversion.out_of_scheme`, unless they are more than
  :data:`MAX_OUT_OF_SCHEME_SHARE` of the scan: then the scheme is wrong for the
  scan (a raw scan with ``label_scheme: learning``, garbage labels) and
  :class:`LabelError` says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mlsemreg_ros.core.resources import share_file
from mlsemreg_ros.core.settings import ConfigError
import numpy as np
import yaml

SCHEMES = ('auto', 'learning', 'raw')
_RAW_MASK = 0xFFFF
_UINT32_MASK = 0xFFFFFFFF

#: ``auto`` picks raw ids when (share of valid raw ids) - (share of valid learning ids)
#: reaches this, over the non-zero values. Measured: raw scans of the simulator
#: 0.95-0.995, learning scans of the KITTI dev pairs -0.20 to -0.39 (their raw-valid
#: values are all also learning-valid: building 13, vegetation 15, car 1, ...).
AUTO_RAW_MARGIN = 0.25

#: Largest share of out-of-scheme values that :meth:`LabelMap.convert` turns into
#: unlabeled; above it the scan is rejected with :class:`LabelError`.
MAX_OUT_OF_SCHEME_SHARE = 0.5


class LabelError(ValueError):
    """Labels cannot be interpreted (unknown scheme or dtype, NaN, non-integral floats)."""


@dataclass(frozen=True)
class LabelConversion:
    """Learning ids of one scan and how they were obtained (:meth:`LabelMap.convert`)."""

    ids: np.ndarray  # (N,) int32 learning ids; out-of-scheme values are 0 (unlabeled)
    scheme: str  # 'learning' or 'raw': the scheme used (decided here for 'auto')
    requested: str  # the scheme asked for: 'auto', 'learning' or 'raw'
    out_of_scheme: int  # values that are not valid ids of `scheme` (now unlabeled)
    raw_share: float  # share of the non-zero values that are valid raw ids (0 if none)
    learning_share: float  # share of the non-zero values that are valid learning ids

    def __len__(self) -> int:
        return int(self.ids.shape[0])


def label_bit_patterns(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """
    Read labels of any integer, bool or float dtype as uint32 bit patterns.

    Returns ``(patterns (N,) int64 in [0, 2**32), fits (N,) bool or None)``; ``fits``
    is False where a value lies outside ``[-2**31, 2**32)`` (its pattern is then 0) and
    None when every value fits. Raises :class:`LabelError` for NaN/inf or non-integral
    floats and for other dtypes.
    """
    values = np.asarray(labels).reshape(-1)
    kind, fits = values.dtype.kind, None
    if kind == 'f':
        if not np.all(np.isfinite(values)):
            raise LabelError('labels contain NaN or inf')
        if np.any(values != np.round(values)):
            raise LabelError('float labels must hold integral values')
        values = values.astype(np.float64, copy=False)  # float16 cannot hold the bounds
        fits = (values >= -(2.0**31)) & (values < 2.0**32)
        values = np.where(fits, values, 0.0)
    elif kind == 'u' and values.dtype.itemsize > 4:
        fits = values <= np.uint64(_UINT32_MASK)
        values = np.where(fits, values, 0)
    elif kind == 'i' and values.dtype.itemsize > 4:
        fits = (values >= -(2**31)) & (values <= _UINT32_MASK)
        values = np.where(fits, values, 0)
    elif kind not in 'iub':
        raise LabelError(f'unsupported label dtype {values.dtype}')
    if fits is not None and fits.all():
        fits = None
    return values.astype(np.int64) & _UINT32_MASK, fits


@dataclass(frozen=True)
class LabelMap:
    """Class names indexed by learning id, plus the raw -> learning lookup table."""

    name: str
    names: tuple[str, ...]
    raw_lut: np.ndarray  # (65536,) int32: raw semantic id -> learning id
    learning_to_raw_ids: np.ndarray  # (num_classes,) int64: canonical raw id per class
    raw_known: np.ndarray | None = None  # (65536,) bool: raw id is a key of the table

    @classmethod
    def load(cls, path: str | Path | None = None) -> LabelMap:
        """Read a label-map YAML (default: ``config/labels/semantic_kitti.yaml``)."""
        path = Path(path) if path is not None else share_file('config/labels/semantic_kitti.yaml')
        data = yaml.safe_load(path.read_text())
        names = tuple(str(n) for n in data['learning'])
        lut = np.zeros(_RAW_MASK + 1, dtype=np.int32)
        known = np.zeros(_RAW_MASK + 1, dtype=bool)
        for raw, learning in data['raw_to_learning'].items():
            if not 0 <= int(learning) < len(names):
                raise ConfigError(f'{path}: raw id {raw} maps to unknown learning id {learning}')
            if not 0 <= int(raw) <= _RAW_MASK:
                raise ConfigError(f'{path}: raw id {raw} is outside 0..{_RAW_MASK}')
            lut[int(raw)] = int(learning)
            known[int(raw)] = True
        to_raw = np.zeros(len(names), dtype=np.int64)
        for learning, raw in data.get('learning_to_raw', {}).items():
            to_raw[int(learning)] = int(raw)
        return cls(str(data.get('name', path.stem)), names, lut, to_raw, known)

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
                f'unknown class {name!r}; known classes: {", ".join(self.names)}'
            ) from None

    def ids_of(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Learning ids of several class names."""
        return np.array([self.id_of(n) for n in names], dtype=np.int64)

    def _known_raw(self) -> np.ndarray:
        """Raw ids that are keys of the table (derived from the LUT if not given)."""
        if self.raw_known is not None:
            return self.raw_known
        known = self.raw_lut != 0  # without the table's keys: ids mapping to a class
        known[0] = True
        return known

    def _validity(
        self, patterns: np.ndarray, fits: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(valid learning id (N,) bool, valid raw id (N,) bool)`` of bit patterns."""
        learning = patterns < self.num_classes
        raw = self._known_raw()[patterns & _RAW_MASK]
        if fits is not None:
            learning &= fits
            raw &= fits
        return learning, raw

    def _shares(
        self, patterns: np.ndarray, learning: np.ndarray, raw: np.ndarray
    ) -> tuple[float, float]:
        """Shares of valid raw and learning ids among the non-zero values."""
        informative = patterns != 0
        count = int(np.count_nonzero(informative))
        if count == 0:
            return 0.0, 0.0
        return (
            float(np.count_nonzero(raw & informative) / count),
            float(np.count_nonzero(learning & informative) / count),
        )

    def detect_scheme(self, labels: np.ndarray) -> str:
        """
        ``'raw'`` or ``'learning'`` for a scan of labels of any dtype, by shares of valid ids.

        Raw when the share of valid raw ids exceeds the share of valid learning ids by at
        least :data:`AUTO_RAW_MARGIN` (over the non-zero values), else learning. A raw scan
        that holds only raw ids that are also learning ids (0, 1, 10, 11, 13, 15, 16, 18
        without instance bits) is read as learning ids; set the scheme for such data.
        """
        patterns, fits = label_bit_patterns(labels)
        learning, raw = self._validity(patterns, fits)
        raw_share, learning_share = self._shares(patterns, learning, raw)
        return 'raw' if raw_share - learning_share >= AUTO_RAW_MARGIN else 'learning'

    def convert(
        self,
        labels: np.ndarray,
        scheme: str = 'auto',
        *,
        max_out_of_scheme: float = MAX_OUT_OF_SCHEME_SHARE,
    ) -> LabelConversion:
        """
        Map labels of any integer or float dtype to learning ids, with the counts.

        ``scheme`` is ``'auto'``, ``'learning'`` or ``'raw'`` (see the module docstring
        for the bit-pattern and ``auto`` rules). Raw ids lose their instance bits (upper
        16) before the lookup. Values that are not valid ids of the scheme (learning ids
        outside ``[0, num_classes)`` or with instance bits, raw ids missing from the
        table, values beyond 32 bits) become 0 (unlabeled) and are counted. Raises
        :class:`LabelError` for an unknown scheme or dtype, NaN/inf or non-integral
        floats, and when more than ``max_out_of_scheme`` (a share, 1 disables) of the
        values are out of the scheme.
        """
        if scheme not in SCHEMES:
            raise LabelError(f'unknown label scheme {scheme!r}; use one of {SCHEMES}')
        patterns, fits = label_bit_patterns(labels)
        learning, raw = self._validity(patterns, fits)
        raw_share, learning_share = self._shares(patterns, learning, raw)
        used = scheme
        if scheme == 'auto':
            used = 'raw' if raw_share - learning_share >= AUTO_RAW_MARGIN else 'learning'
        if used == 'raw':
            valid = raw
            ids = np.where(valid, self.raw_lut[patterns & _RAW_MASK], 0).astype(np.int32)
        else:
            valid = learning
            ids = np.where(valid, patterns, 0).astype(np.int32)
        out = int(valid.size - np.count_nonzero(valid))
        if out > max_out_of_scheme * valid.size:
            raise LabelError(self._rejection(used, scheme, out, valid.size, max_out_of_scheme))
        return LabelConversion(ids, used, scheme, out, raw_share, learning_share)

    def _rejection(self, used: str, requested: str, out: int, total: int, limit: float) -> str:
        """Explain why a scan's labels are rejected (too many out-of-scheme values)."""
        what = (
            f'learning ids must lie in [0, {self.num_classes - 1}] without instance bits'
            if used == 'learning'
            else f'raw ids must be keys of the {self.name} raw -> learning table'
        )
        how = (
            f'label_scheme auto read the scan as {used} ids'
            if requested == 'auto'
            else f'label_scheme {used}'
        )
        return (
            f'{what}: {out} of {total} values ({100.0 * out / total:.1f} %) are not, more '
            f'than the {100.0 * limit:g} % that may become unlabeled ({how})'
        )

    def to_learning(self, labels: np.ndarray, scheme: str = 'auto') -> np.ndarray:
        """
        Map labels of any integer or float dtype to learning ids (N,) int32.

        The ids of :meth:`convert` (which also reports the decided scheme and the
        number of out-of-scheme values, now unlabeled).
        """
        return self.convert(labels, scheme).ids

    def to_raw(self, learning: np.ndarray, instance: np.ndarray | None = None) -> np.ndarray:
        """Canonical raw ids (uint32) of learning ids, optionally with instance ids."""
        raw = self.learning_to_raw_ids[np.asarray(learning, dtype=np.int64)].astype(np.uint32)
        if instance is not None:
            raw |= (np.asarray(instance, dtype=np.uint32) & _RAW_MASK) << np.uint32(16)
        return raw
