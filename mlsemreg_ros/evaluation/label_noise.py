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
Label noise as a segmentation network makes it, for the benchmarks (docs/label_noise.md).

A spec is ``kind:share`` items joined by ``,`` (``flip:0.2``, ``confuse:0.3``,
``flip:0.1,confuse:0.3``):

- ``flip:f``: a share ``f`` of the points get a uniformly drawn learning id (any of the
  label map's ids, possibly their own);
- ``confuse:c``: a share ``c`` of the points of each class of :data:`CONFUSIONS` get a
  partner class (building <-> vegetation, road <-> sidewalk, terrain <-> vegetation;
  vegetation points take building or terrain, drawn evenly), the habitual confusions of
  a network.

Noise is applied to learning ids (:meth:`LabelNoise.apply`); raw ids are converted first
and written back as canonical raw ids. Every scan gets its own seeded generator.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.simulation.degrade import class_confusions
import numpy as np

#: The confusions of ``confuse:c`` (class names of the label map), both ways.
CONFUSIONS = (('building', 'vegetation'), ('road', 'sidewalk'), ('terrain', 'vegetation'))

KINDS = ('flip', 'confuse')


class LabelNoiseError(ValueError):
    """A ``--label-noise`` spec that cannot be read."""


@dataclass(frozen=True)
class LabelNoise:
    """Shares of flipped and confused points (0: none); see the module docstring."""

    flip: float = 0.0
    confuse: float = 0.0

    @classmethod
    def parse(cls, spec: str | None) -> LabelNoise:
        """Read ``flip:0.2``, ``confuse:0.3``, ``flip:0.1,confuse:0.3``, ``none`` or ''."""
        shares = dict.fromkeys(KINDS, 0.0)
        text = (spec or '').strip()
        if text in ('', 'none'):
            return cls()
        for item in text.split(','):
            kind, sep, value = item.strip().partition(':')
            if not sep or kind not in KINDS:
                raise LabelNoiseError(
                    f'label noise {item.strip()!r}: expected kind:share with kind one of '
                    f'{", ".join(KINDS)} (e.g. flip:0.2)'
                )
            try:
                share = float(value)
            except ValueError:
                raise LabelNoiseError(
                    f'label noise {item.strip()!r}: share is not a number'
                ) from None
            if not 0.0 <= share <= 1.0:
                raise LabelNoiseError(f'label noise {item.strip()!r}: share outside [0, 1]')
            shares[kind] = share
        return cls(**shares)

    @property
    def active(self) -> bool:
        """Whether any label changes."""
        return self.flip > 0.0 or self.confuse > 0.0

    def __str__(self) -> str:
        parts = [f'{k}:{getattr(self, k):g}' for k in KINDS if getattr(self, k) > 0.0]
        return ','.join(parts) or 'none'

    def apply_learning(
        self, ids: np.ndarray, label_map: LabelMap, rng: np.random.Generator
    ) -> np.ndarray:
        """Noisy copy of ``(N,)`` learning ids (confusions first, then flips)."""
        out = np.asarray(ids).copy()
        if self.confuse > 0.0:
            pairs = [tuple(label_map.ids_of(list(p))) for p in CONFUSIONS]
            out = class_confusions(out, self.confuse, pairs, rng)
        if self.flip > 0.0:
            hit = rng.random(out.size) < self.flip
            out[hit] = rng.integers(0, label_map.num_classes, int(hit.sum()))
        return out

    def apply(
        self,
        labels: np.ndarray,
        label_map: LabelMap,
        rng: np.random.Generator,
        scheme: str = 'auto',
    ) -> np.ndarray:
        """Noisy labels in the scheme they came in (raw ids come back canonical, no instance)."""
        if not self.active:
            return labels
        conversion = label_map.convert(labels, scheme)
        noisy = self.apply_learning(conversion.ids, label_map, rng)
        if conversion.scheme == 'raw':
            return label_map.to_raw(noisy)
        return noisy.astype(np.int32)


def scan_rng(seed: int, index: int, scan: int) -> np.random.Generator:
    """Return the generator of scan ``scan`` (0 source, 1 target) of pair ``index``."""
    return np.random.default_rng([seed, 21, index, scan])


#: The levels of the sweep in docs/label_noise.md.
SWEEP = ('none', 'flip:0.1', 'flip:0.2', 'flip:0.3', 'confuse:0.1', 'confuse:0.3', 'confuse:0.5')


def sweep_row(descriptor: str, noise: str, report: dict[str, Any]) -> dict[str, Any]:
    """RR, accepted (right / wrong), IR and label agreement of one eval-pairs report."""
    pairs = report['pairs']
    right = [p for p in pairs if p['success']]
    ceilings = [p['evidence'].get('label_ceiling', float('nan')) for p in right]
    ceilings = [c for c in ceilings if c is not None and np.isfinite(c)]
    return {
        'descriptor': descriptor,
        'noise': noise,
        'pairs': len(pairs),
        'rr_pct': 100.0 * len(right) / len(pairs),
        'accepted_right': sum(bool(p['accepted']) for p in right),
        'accepted_right_pct': 100.0 * sum(bool(p['accepted']) for p in right) / max(len(right), 1),
        'wrong_accepted': sum(bool(p['accepted']) and not p['success'] for p in pairs),
        'ir_pct': float(np.mean([p['inlier_ratio_pct'] for p in pairs])),
        'agreement_right_min': min((p['evidence']['label_agreement'] for p in right), default=0),
        'ceiling_right_mean': float(np.mean(ceilings)) if ceilings else float('nan'),
    }


def plot_sweep(rows: list[dict[str, Any]], path: Any) -> None:
    """Plot the accepted share of the right poses, RR and IR per noise level and descriptor."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    levels = list(dict.fromkeys(r['noise'] for r in rows))
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
    x = np.arange(len(levels))
    for offset, descriptor in ((-0.2, 'gedi'), (0.2, 'fpfh')):
        mine = {r['noise']: r for r in rows if r['descriptor'] == descriptor}
        if not mine:
            continue
        acc = [mine[n]['accepted_right_pct'] if n in mine else np.nan for n in levels]
        rr = [mine[n]['rr_pct'] if n in mine else np.nan for n in levels]
        wrong = [mine[n]['wrong_accepted'] if n in mine else 0 for n in levels]
        left.bar(x + offset, acc, 0.38, label=f'{descriptor.upper()}: accepted of the right')
        left.plot(x + offset, rr, 'k_', ms=14, mew=2)
        for xi, w in zip(x + offset, wrong, strict=True):
            left.text(xi, 3, f'{w} wrong', rotation=90, ha='center', va='bottom', fontsize=8)
        right.plot(x, [mine[n]['ir_pct'] for n in levels], 'o-', label=descriptor.upper())
    left.axhline(90, color='tab:red', lw=0.8, ls='--')
    left.axhline(80, color='tab:orange', lw=0.8, ls=':')
    left.set(xticks=x, xticklabels=levels, ylim=(0, 125), ylabel='% (bars: accepted; -: RR)')
    left.set_title('dev pairs: accepted share of the right poses, RR (black)')
    left.legend(loc='upper left', ncol=2, fontsize=8)
    for axis in (left, right):
        axis.tick_params(axis='x', labelrotation=25)
    right.set(xticks=x, xticklabels=levels, ylabel='inlier ratio %', title='inlier ratio')
    right.legend()
    fig.savefig(path, dpi=110)
    plt.close(fig)
