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
Registration pair files (``.npz``) of the paper's evaluation protocol.

A pair file holds ``pts_src, label_src, kpts_src, <desc>_src, pts_dst,
label_dst, kpts_dst, <desc>_dst, trans_gt``; ``trans_gt`` (4x4) maps source
points onto the target (``T_target_source``); keypoints are members of
``pts_*``; ``<desc>`` names a descriptor such as ``gedi`` (one row per keypoint).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import itertools
import os
from pathlib import Path

import numpy as np

_REQUIRED = ('pts_src', 'label_src', 'pts_dst', 'label_dst', 'trans_gt')
#: The real KITTI dev pairs: beside the repository, never inside it.
DEV_PAIRS = Path(__file__).resolve().parents[3] / 'shared' / 'data' / 'kitti_pairs_dev'


class PairFileError(ValueError):
    """A pair file misses a key or holds arrays of inconsistent shapes."""


@dataclass
class Pair:
    """One registration pair read from a ``.npz`` file."""

    name: str  # file stem, e.g. '000003'
    pts_src: np.ndarray  # (N, 3) float64, metres
    label_src: np.ndarray  # (N,) labels as stored (learning or raw ids)
    pts_dst: np.ndarray  # (N', 3) float64
    label_dst: np.ndarray  # (N',)
    trans_gt: np.ndarray  # (4, 4) float64 T_target_source
    kpts_src: np.ndarray | None = None  # (M, 3) float64 or None when absent
    kpts_dst: np.ndarray | None = None  # (M', 3)
    descriptors_src: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (M, D)
    descriptors_dst: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (M', D)

    @property
    def descriptor_names(self) -> list[str]:
        """Descriptors stored for both clouds, e.g. ``['gedi']``."""
        return sorted(set(self.descriptors_src) & set(self.descriptors_dst))

    def descriptors(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(source (M, D), target (M', D))`` descriptors called ``name``."""
        if name not in self.descriptor_names:
            raise KeyError(
                f'pair {self.name} has no {name!r} descriptors '
                f'(stored: {self.descriptor_names or "none"})'
            )
        return self.descriptors_src[name], self.descriptors_dst[name]


def load_pair(path: str | Path) -> Pair:
    """Read a pair file; raises :class:`PairFileError` naming what is missing or wrong."""
    path = Path(path)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    missing = [k for k in _REQUIRED if k not in arrays]
    if missing:
        raise PairFileError(f'{path}: missing key(s) {missing}')
    pair = Pair(
        name=path.stem,
        pts_src=np.asarray(arrays['pts_src'], dtype=np.float64).reshape(-1, 3),
        label_src=arrays['label_src'].reshape(-1),
        pts_dst=np.asarray(arrays['pts_dst'], dtype=np.float64).reshape(-1, 3),
        label_dst=arrays['label_dst'].reshape(-1),
        trans_gt=np.asarray(arrays['trans_gt'], dtype=np.float64).reshape(4, 4),
        kpts_src=_optional_points(arrays.get('kpts_src')),
        kpts_dst=_optional_points(arrays.get('kpts_dst')),
    )
    reserved = {'pts', 'label', 'kpts'}
    for key, value in arrays.items():
        stem, _, side = key.rpartition('_')
        if stem and stem not in reserved and side in ('src', 'dst'):
            target = pair.descriptors_src if side == 'src' else pair.descriptors_dst
            target[stem] = np.asarray(value).reshape(value.shape[0], -1)
    _check(path, pair)
    return pair


def _optional_points(value: np.ndarray | None) -> np.ndarray | None:
    return None if value is None else np.asarray(value, dtype=np.float64).reshape(-1, 3)


def _check(path: Path, pair: Pair) -> None:
    for side in ('src', 'dst'):
        pts, labels = getattr(pair, f'pts_{side}'), getattr(pair, f'label_{side}')
        if labels.shape[0] != pts.shape[0]:
            raise PairFileError(
                f'{path}: {pts.shape[0]} pts_{side} but {labels.shape[0]} label_{side}'
            )
        kpts = getattr(pair, f'kpts_{side}')
        for name, desc in getattr(pair, f'descriptors_{side}').items():
            if kpts is None or desc.shape[0] != kpts.shape[0]:
                raise PairFileError(
                    f'{path}: {name}_{side} has {desc.shape[0]} rows but '
                    f'kpts_{side} has '
                    f'{"none" if kpts is None else kpts.shape[0]}'
                )


def list_pairs(directory: str | Path) -> list[Path]:
    """Pair files (``*.npz``) of a directory, sorted by name."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f'{directory} is not a directory')
    return sorted(p for p in directory.glob('*.npz') if p.is_file())


def save_pair(path: str | Path, pair: Pair) -> Path:
    """
    Write ``pair`` in the pair-file layout (inverse of :func:`load_pair`).

    Keypoints and descriptors are written only when present.
    """
    arrays: dict[str, np.ndarray] = {
        'pts_src': pair.pts_src,
        'label_src': pair.label_src,
        'pts_dst': pair.pts_dst,
        'label_dst': pair.label_dst,
        'trans_gt': pair.trans_gt,
    }
    if pair.kpts_src is not None:
        arrays['kpts_src'] = pair.kpts_src
    if pair.kpts_dst is not None:
        arrays['kpts_dst'] = pair.kpts_dst
    for name, desc in pair.descriptors_src.items():
        arrays[f'{name}_src'] = desc
    for name, desc in pair.descriptors_dst.items():
        arrays[f'{name}_dst'] = desc
    path = Path(path)
    np.savez(path, **arrays)
    return path


def dev_pairs_dir() -> Path:
    """Return the KITTI dev pairs folder (environment ``MLSEMREG_DEV_PAIRS`` overrides it)."""
    env = os.environ.get('MLSEMREG_DEV_PAIRS')
    return Path(env) if env else DEV_PAIRS


def first_dev_pair() -> Path | None:
    """Return the first KITTI dev pair file, or None when the dev pairs are absent."""
    folder = dev_pairs_dir()
    files = list_pairs(folder) if folder.is_dir() else []
    return files[0] if files else None


class ChainError(ValueError):
    """Pair files that do not form a chain (``pts_dst`` of one is not ``pts_src`` of the next)."""


def chained(first: Pair, second: Pair, atol: float = 1e-9) -> bool:
    """Tell whether ``second`` starts where ``first`` ends (same target / source scan)."""
    return (
        first.pts_dst.shape == second.pts_src.shape
        and np.allclose(first.pts_dst, second.pts_src, rtol=0.0, atol=atol)
        and np.array_equal(first.label_dst, second.label_src)
    )


def compose_chain(pairs: list[Pair], name: str | None = None) -> Pair:
    """
    One pair from the first scan of a chain of pairs to the last one.

    ``pairs[k].pts_dst`` must be ``pairs[k + 1].pts_src`` (:func:`chained`). The source
    side (points, labels, keypoints, descriptors) is ``pairs[0]``'s, the target side
    ``pairs[-1]``'s, and ``trans_gt = trans_gt[-1] @ ... @ trans_gt[0]`` (each maps its
    source onto its target). Raises :class:`ChainError` when a link is broken.
    """
    if not pairs:
        raise ChainError('compose_chain needs at least one pair')
    for first, second in itertools.pairwise(pairs):
        if not chained(first, second):
            raise ChainError(
                f'{second.name} does not start where {first.name} ends '
                '(its pts_src/label_src differ from the pts_dst/label_dst before it)'
            )
    trans_gt = np.eye(4)
    for pair in pairs:
        trans_gt = pair.trans_gt @ trans_gt
    head, tail = pairs[0], pairs[-1]
    return Pair(
        name=name or f'{head.name}_{tail.name}',
        pts_src=head.pts_src,
        label_src=head.label_src,
        pts_dst=tail.pts_dst,
        label_dst=tail.label_dst,
        trans_gt=trans_gt,
        kpts_src=head.kpts_src,
        kpts_dst=tail.kpts_dst,
        descriptors_src=dict(head.descriptors_src),
        descriptors_dst=dict(tail.descriptors_dst),
    )


def reversed_pair(pair: Pair, name: str | None = None) -> Pair:
    """Return the same two scans the other way round: target as source, ``inv(trans_gt)``."""
    return Pair(
        name=name or f'{pair.name}_rev',
        pts_src=pair.pts_dst,
        label_src=pair.label_dst,
        pts_dst=pair.pts_src,
        label_dst=pair.label_src,
        trans_gt=np.linalg.inv(pair.trans_gt),
        kpts_src=pair.kpts_dst,
        kpts_dst=pair.kpts_src,
        descriptors_src=dict(pair.descriptors_dst),
        descriptors_dst=dict(pair.descriptors_src),
    )


def chain_pairs(pairs: list[Pair], apart: int, reverse: bool = False) -> list[Pair]:
    """
    Every pair of scans ``apart`` links apart along a chain of pairs (``apart=1``: as given).

    ``pairs`` in chain order; ``len(pairs) - apart + 1`` pairs come out, pair ``k``
    from the source scan of ``pairs[k]`` to the target scan of ``pairs[k + apart - 1]``
    (named ``<first>_<last>``, :func:`compose_chain`). ``reverse`` swaps every pair's
    source and target (:func:`reversed_pair`, name suffix ``_rev``).
    """
    if apart < 1:
        raise ValueError(f'apart must be at least 1, got {apart}')
    out = []
    for k in range(len(pairs) - apart + 1):
        window = pairs[k:][:apart]
        pair = compose_chain(window, f'{window[0].name}_{window[-1].name}')
        out.append(reversed_pair(pair) if reverse else pair)
    return out
