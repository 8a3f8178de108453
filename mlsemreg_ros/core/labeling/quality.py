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

The labels are a noisy channel: each scan's labels are its true classes, some of them
flipped or confused. Before a pair is matched its labels are judged (docs/labels.md):

- **how much they say at all**: the labels' information, the agreement beyond chance
  (Cohen's kappa) of each scan's labels with their nearest neighbours' in the same scan,
  geometric mean of both (core/estimation/label_model.py ``information_ceiling``; dev
  pairs 0.87-0.96 as given, 0.14-0.46 with 30 % flips, 0.01-0.08 with 70 %). Below
  ``confidence.min_label_information`` they are **no better than chance**: the pair is
  matched and judged as unlabeled, through views of the two scans without labels (every
  keypoint in every group, no landmarks), exactly as ``label_source: none`` would;
- **their weight** ``w`` in ``[0, 1]``: the labels' ceiling ``c`` (the geometric mean of the
  two scans' label self-agreement; clean network labels 0.90-0.96, 30 % flips 0.52-0.57)
  places them between ``c0 = confidence.min_label_ceiling`` and ``c1 =
  confidence.contradiction_min_ceiling``, ``w = clip((c - c0) / (c1 - c0), 0, 1)``, times
  ``geometric_labels.trust`` when either scan was labelled by the geometric labeler (its
  self-agreement is high whatever its agreement across scans).

**Poorer labels** (``w < FULL_WEIGHT``, 0.75; one path, decided here, no second run):

- Group Matching widens: every keypoint also keeps its nearest descriptor over all groups
  (:func:`widened`), so a keypoint whose true partner carries another label is still
  matched;
- the geometric evidence carries the decision: the verification score weighs the label
  agreement by ``sqrt(w)`` (``verification.label_weight * sqrt(w)``: at ``w = 0`` the
  overlap alone, as without labels), the contradiction check is off, and below
  ``OBJECTS_MIN_WEIGHT`` the distinctive objects decide nothing and the ground fitted to
  the labels levels nothing (``levelling.enabled`` off for the pair);
- the geometric labeler's ground holds slopes and sidewalks, so its pairs' tilt check
  allows ``geometric_labels.tilt_tolerance`` (whatever their weight);
- the labels keep a veto by likelihood rather than raw agreement
  (``confidence.label_rule: information``): the pose's label co-occurrence must agree
  beyond chance by at least ``confidence.min_relative_information`` of what the labels
  give against themselves. A wrong pose on a street still agrees on road and facades, but
  no more than chance would; a right pose under 30 % flips agrees less, and so do the
  labels against themselves.
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

#: From this weight on the labels count in full (mild noise changes nothing).
FULL_WEIGHT = 0.75
#: Below this weight the distinctive objects decide nothing.
OBJECTS_MIN_WEIGHT = 0.5


@dataclass(frozen=True)
class LabelQuality:
    """The judged labels of one pair and what follows from them."""

    weight: float  # 0: no better than chance ... 1: as clean as clean network labels
    ceiling: float  # the labels' ceiling (NaN: unknown)
    information: float  # their agreement beyond chance against themselves (NaN: unknown)
    source: str  # the label source of the pair ('field', 'geometric', 'onnx', 'none')
    unlabeled: bool  # matched and judged as unlabeled
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def widen(self) -> bool:
        """Whether Group Matching widens: poorer labels (0 < weight < FULL_WEIGHT)."""
        return not self.unlabeled and self.weight < FULL_WEIGHT

    def config(self, config: Any) -> Any:
        """``config`` with the semantic evidence weighed by :attr:`weight` (itself at >= 0.75)."""
        sections = {}
        if self.source == 'geometric' and not self.unlabeled:
            # its ground holds slopes and sidewalks: a wider tilt check (docs/labels.md)
            tolerance = max(config.levelling.tolerance, config.geometric_labels.tilt_tolerance)
            sections['levelling'] = replace(config.levelling, tolerance=tolerance)
        if self.unlabeled or self.weight >= FULL_WEIGHT:
            return replace(config, **sections) if sections else config
        conf, ver = config.confidence, config.verification
        changes = {'label_rule': 'information', 'contradicting_objects': 0}
        if self.weight < OBJECTS_MIN_WEIGHT:
            changes['min_distinctive_ceiling'] = 1.0  # objects decide only when spotless
            # nor does a ground fitted to their road labels (30 % flips: a right pose of dev
            # pair 000012 refused as 7.4 deg off the flipped ground)
            sections['levelling'] = replace(
                sections.get('levelling', config.levelling), enabled=False
            )
        weighed = ver.label_weight * math.sqrt(self.weight)
        return replace(
            config,
            confidence=replace(conf, **changes),
            verification=replace(ver, label_weight=weighed),
            **sections,
        )


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
    ceiling = information = float('nan')
    if not unlabeled:
        ceiling = label_model.label_ceiling(source, target, compatibility, config.verification)
        information = label_model.information_ceiling(
            source, target, compatibility, config.verification
        )
    conf = config.confidence
    low, high = conf.min_label_ceiling, max(conf.contradiction_min_ceiling, 1e-6)
    weight = 1.0
    if math.isfinite(ceiling) and high > low:
        weight = float(np.clip((ceiling - low) / (high - low), 0.0, 1.0))
    if kind == 'geometric':
        weight *= config.geometric_labels.trust
    chance = unlabeled or not information >= conf.min_label_information  # NaN: chance
    diagnostics = {
        'label_weight': 0.0 if chance else weight,
        'label_pair_source': kind,
        'labels_judged_unlabeled': bool(chance and not unlabeled),
        'label_information': information,
    }
    return LabelQuality(0.0 if chance else weight, ceiling, information, kind, chance, diagnostics)


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
