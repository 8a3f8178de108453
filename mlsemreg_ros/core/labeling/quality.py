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
Never worse than no labels: judge a pair's labels and weigh the semantic evidence by them.

Before a pair is matched, its labels get a weight ``w`` in ``[0, 1]`` (docs/labels.md):

- the labels' ceiling ``c`` (core/estimation/label_model.py: the geometric mean of the two
  scans' label self-agreement; clean network labels 0.90-0.96, 30 % flips 0.52-0.57)
  places them between chance and clean: ``w_c = clip((c - c0) / (c1 - c0), 0, 1)`` with
  ``c0 = confidence.min_label_ceiling`` and ``c1 = confidence.contradiction_min_ceiling``;
- labels that are smooth but made by geometry are as trustworthy as
  ``geometric_labels.trust`` says: their self-agreement is high whatever their
  agreement across scans, so ``w = w_c * trust`` when either scan was labelled by the
  geometric labeler (its ``input_stats['label_source']``, else ``label_source``).

Then:

- **poorer labels widen Group Matching** (``0 < w < FULL_WEIGHT``, 0.75): every keypoint
  also keeps its nearest descriptor over all groups (:func:`widened`), so a keypoint whose
  true partner carries another label is still matched;
- **no better than chance** (``c < c0``, or both scans unlabeled): the pair is matched
  and judged as unlabeled. Views of the two scans without labels (every keypoint in
  every group, no landmarks) go through the same pipeline, exactly as ``label_source:
  none`` would give them; before, such a pair was refused outright;
- **a refused pair with poorer labels** is registered again as unlabeled (the fallback,
  ``Registration.register``), and that result is taken when it is accepted: what no
  labels would accept is accepted;
- **poorer labels** (``w < FULL_WEIGHT``): the label checks give way to the geometric evidence
  (overlap, inliers, rivals). The label agreement needed shrinks to ``1 - (1 - w) *
  LABEL_RELIEF`` of its value (``confidence.min_relative_agreement`` and
  ``min_label_agreement``), the contradiction check is off, and below ``w = 0.5`` the
  distinctive objects decide nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Any

from mlsemreg_ros.core.estimation import label_model
from mlsemreg_ros.core.labeling.source import resolve
from mlsemreg_ros.core.matching.landmarks import Landmarks
from mlsemreg_ros.core.results import Correspondences, PreparedScan
import numpy as np

#: Share of the label-agreement thresholds that poor labels (w = 0) no longer need.
LABEL_RELIEF = 0.25
#: From this weight on the labels count in full (mild noise changes nothing).
FULL_WEIGHT = 0.75
#: Below this weight the distinctive objects decide nothing.
OBJECTS_MIN_WEIGHT = 0.5


@dataclass(frozen=True)
class LabelQuality:
    """The judged labels of one pair and what follows from them."""

    weight: float  # 0: no better than chance ... 1: as clean as clean network labels
    ceiling: float  # the labels' ceiling (NaN: unknown)
    source: str  # the label source of the pair ('field', 'geometric', 'onnx', 'none')
    unlabeled: bool  # matched and judged as unlabeled
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def widen(self) -> bool:
        """Whether Group Matching widens: poorer labels (0 < weight < FULL_WEIGHT)."""
        return not self.unlabeled and self.weight < FULL_WEIGHT

    def config(self, config: Any) -> Any:
        """``config`` with the label checks weighed by :attr:`weight` (itself at weight 1)."""
        if self.unlabeled or self.weight >= FULL_WEIGHT:
            return config
        conf = config.confidence
        scale = 1.0 - (1.0 - self.weight) * LABEL_RELIEF
        changes = {
            'min_relative_agreement': conf.min_relative_agreement * scale,
            'min_label_agreement': conf.min_label_agreement * scale,
            'contradicting_objects': 0,
        }
        if self.weight < OBJECTS_MIN_WEIGHT:
            changes['min_distinctive_ceiling'] = 1.0  # objects decide only when spotless
        return replace(config, confidence=replace(conf, **changes))


def widened(semantic: Correspondences, plain: Correspondences) -> Correspondences:
    """
    Return the union of the semantic and the plain correspondences (duplicates once).

    Poorer labels put a keypoint's true partner in another group often enough that Group
    Matching alone can find fewer inliers than no labels at all (geometric labels on the
    dev pairs: 4-15 inliers where plain matching found 28-37); each keypoint also keeps its
    nearest descriptor over all groups, as without labels.
    """
    source = np.concatenate([semantic.source, plain.source])
    target = np.concatenate([semantic.target, plain.target])
    distance = np.concatenate([semantic.distance, plain.distance])
    key = source.astype(np.int64) * (int(target.max(initial=0)) + 1) + target
    _, first = np.unique(key, return_index=True)
    first = np.sort(first)
    return Correspondences(source[first], target[first], distance[first])


def pair_source(source: PreparedScan, target: PreparedScan, config: Any) -> str:
    """Return the label source of a pair: ``geometric`` if either scan's, else the first."""
    noted = [s.input_stats.get('label_source') for s in (source, target)]
    if 'geometric' in noted:
        return 'geometric'
    for value in noted:
        if value:
            return str(value)
    return resolve(getattr(config, 'label_source', 'auto'), True)


def judge(
    source: PreparedScan, target: PreparedScan, config: Any, compatibility: Any
) -> LabelQuality:
    """Judge the labels of a pair (module docstring); ``compatibility`` as the pipeline's."""
    kind = pair_source(source, target, config)
    unlabeled = not (np.any(source.labels) or np.any(target.labels))
    ceiling = float('nan')
    if not unlabeled:
        ceiling = label_model.label_ceiling(source, target, compatibility, config.verification)
    conf = config.confidence
    low, high = conf.min_label_ceiling, max(conf.contradiction_min_ceiling, 1e-6)
    weight = 1.0
    if math.isfinite(ceiling) and high > low:
        weight = float(np.clip((ceiling - low) / (high - low), 0.0, 1.0))
    if kind == 'geometric':
        weight *= config.geometric_labels.trust
    chance = unlabeled or (math.isfinite(ceiling) and ceiling < low)
    diagnostics = {
        'label_weight': 0.0 if chance else weight,
        'label_pair_source': kind,
        'labels_judged_unlabeled': bool(chance and not unlabeled),
    }
    return LabelQuality(0.0 if chance else weight, ceiling, kind, chance, diagnostics)


def unlabeled_view(scan: PreparedScan, wildcard: np.ndarray) -> PreparedScan:
    """
    Return the scan without labels: every point unlabeled, every keypoint in every group.

    Shares the points, keypoints, descriptors and KD-tree (nothing is computed again).
    ``wildcard`` (C,) bool is the Local-SS of a keypoint that sees only undefined labels
    (every class but the ignored and undefined ones), as a scan of zeros would give.
    """
    local_ss = np.broadcast_to(wildcard, scan.local_ss.shape).copy()
    return replace(
        scan,
        labels=np.zeros_like(scan.labels),
        local_ss=local_ss,
        landmarks=Landmarks.empty(),
        timings_ms=scan.timings_ms,
        alignment_clouds=scan.alignment_clouds,
        input_stats=scan.input_stats,
        kdtree=scan.kdtree,
        pending_features=None,
        map_excluded=scan.map_excluded,
    )
