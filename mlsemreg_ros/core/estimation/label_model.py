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
How much label agreement the labels of a pair can give, and a label model that learns.

**The label ceiling** (docs/label_noise.md). The label agreement ``A`` of a pose
(:func:`~mlsemreg_ros.core.estimation.verification.dense_scores`: the share of the overlapping,
labeled seen surface whose source and target labels agree) is bounded by how noisy the
two scans' labels are. With a share ``f`` of independently mislabeled points in each scan,
the right pose agrees on about ``(1 - f_s) (1 - f_t) A_clean``. The *self-agreement*
``a_s`` of a scan, the same agreement between each sampled point and its nearest other
point of the same scan (:func:`self_agreement`), shrinks by ``(1 - f_s)^2``. So

    ``ceiling = sqrt(a_source * a_target)``,  ``relative = A / ceiling``

keeps the clean value of ``relative`` whatever the noise, for the right pose and for a
wrong one alike: the rule ``relative >= confidence.min_relative_agreement`` separates
them as the fixed rule does on clean labels. Both use the same label compatibility
(fixed, or learned by :class:`LabelModel`), so a learned confusion raises both.

Hypothesis verification and the BEV search compare poses of one pair, whose ceiling is
the same: the ceiling changes no choice, only the acceptance.

**The distinctive ceiling** (:func:`distinctive_ceiling`): the same self-agreement for the
classes of the distinctive objects only (poles, signs, trunks). It says whether those
objects mean what they mean on clean labels (confidence.py, ``objects_trusted``).

**The adaptive label model** (``confidence.label_model: adaptive``). A network confuses
some classes habitually (a wall as vegetation). :class:`LabelModel` counts, at accepted
poses, which target label lies under which source label (:func:`cooccurrence`), and
turns the counts ``N(a, b)`` (source label a over target label b) into compatibility
weights: the pair agrees with weight ``w(a, b) = clip((r(a, b) - r0) / (1 - r0), 0, 1)``,
``r(a, b) = max(N(a, b) / N(a, a), N(b, a) / N(b, b))`` (how often a class is seen as the
other per time it is seen as itself, either way), ``r0 =
confidence.label_min_association``: boundary coincidences (``r`` a few %) stay
disagreements, a class seen as another 40 % of the time (``r = 0.67``) counts 0.6.
"""

from __future__ import annotations

import math
from typing import Any

from mlsemreg_ros.core.estimation.config import ConfidenceConfig, VerificationConfig
from mlsemreg_ros.core.results import PreparedScan
import numpy as np

RULES = ('relative', 'fixed', 'information')
MODELS = ('fixed', 'adaptive')


def _sample_rows(total: int, config: VerificationConfig) -> np.ndarray:
    rng = np.random.default_rng(config.seed)
    if total > config.sample_points:
        return rng.choice(total, config.sample_points, replace=False)
    return np.arange(total)


def _area_weights(points: np.ndarray, exponent: float) -> np.ndarray:
    from mlsemreg_ros.core.estimation.verification import area_weights

    return area_weights(points, exponent)


def self_agreement(scan: PreparedScan, labels: Any, config: VerificationConfig) -> float:
    """
    Label agreement of a scan with itself: each sampled point against its nearest neighbour.

    The seeded sample, the range weights, the counted classes and the compatibility
    (``labels``: a :class:`~mlsemreg_ros.core.estimation.verification.LabelCompatibility`, boolean
    or
    weighted) are those of the dense scores; the neighbour is the nearest *other* point
    within ``overlap_distance``. NaN when no sampled point has a counted neighbour.
    """
    total = scan.points.shape[0]
    if total < 2:
        return float('nan')
    rows = _sample_rows(total, config)
    points, own = scan.points[rows], scan.labels[rows]
    distance, nearest = scan.points_tree().query(
        points, k=2, distance_upper_bound=config.overlap_distance
    )
    found = np.isfinite(distance[:, 1])
    neighbour = np.where(found, nearest[:, 1], 0)
    other = scan.labels[neighbour]
    counted = found & labels.counted[own] & labels.counted[other]
    weight = _area_weights(points, config.range_exponent) * counted
    if weight.sum() <= 0:
        return float('nan')
    agree = np.asarray(labels.compatible[own, other], dtype=np.float64)
    return float((agree * weight).sum() / weight.sum())


def label_ceiling(
    source: PreparedScan, target: PreparedScan, labels: Any, config: VerificationConfig
) -> float:
    """``sqrt(self_agreement(source) * self_agreement(target))``; NaN if unknown."""
    a = self_agreement(source, labels, config)
    b = self_agreement(target, labels, config)
    return math.sqrt(a * b) if a > 0 and b > 0 else float('nan')


def label_refusal(
    label_agreement: float,
    ceiling: float,
    config: ConfidenceConfig,
    information: float = float('nan'),
    information_ceiling: float = float('nan'),
) -> str:
    """
    Why the label agreement is not enough ('' when it is), by ``confidence.label_rule``.

    ``fixed``: ``label_agreement >= min_label_agreement``. ``relative``: ``label_agreement
    / ceiling >= min_relative_agreement`` and ``label_agreement >= label_floor``; a NaN
    ceiling (no labeled neighbours) falls back to the fixed rule. ``information`` (the rule
    of poorer labels, core/labeling/quality.py): the pose's agreement beyond chance
    (:func:`information`) must reach ``min_relative_information`` of what the labels give
    against themselves (:func:`information_ceiling`); unknown values pass (the geometric
    evidence decides).
    """
    if config.label_rule == 'information':
        if not (information_ceiling > 0 and np.isfinite(information)):
            return ''
        share = information / information_ceiling
        if share >= config.min_relative_information:
            return ''
        return (
            f'label information {information:.3f} = {share:.3f} of what the labels give '
            f'({information_ceiling:.3f}) < confidence.min_relative_information='
            f'{config.min_relative_information:g}'
        )
    fixed = (
        ''
        if label_agreement >= config.min_label_agreement
        else f'label agreement {label_agreement:.3f} < '
        f'confidence.min_label_agreement={config.min_label_agreement:g}'
    )
    if config.label_rule == 'fixed' or not ceiling > 0:
        return fixed
    if label_agreement < config.label_floor:
        return (
            f'label agreement {label_agreement:.3f} < confidence.label_floor='
            f'{config.label_floor:g}'
        )
    relative = label_agreement / ceiling
    if relative < config.min_relative_agreement:
        return (
            f"label agreement {label_agreement:.3f} = {relative:.3f} of the labels' ceiling "
            f'{ceiling:.3f} < confidence.min_relative_agreement='
            f'{config.min_relative_agreement:g}'
        )
    return ''


def cooccurrence(
    transform: np.ndarray,
    source: PreparedScan,
    target: PreparedScan,
    num_classes: int,
    config: VerificationConfig,
) -> np.ndarray:
    """
    ``(C, C)`` range-weighted counts of (source label, target label) at ``transform``.

    The seeded source sample of the dense scores, moved by ``transform``; its nearest
    target point within ``overlap_distance``. Weights ``range ** range_exponent``,
    normalised to a mean of 1 per sampled point (so a count is about a number of points).
    """
    counts = np.zeros((num_classes, num_classes))
    total = source.points.shape[0]
    if total == 0 or target.points.shape[0] == 0 or not np.all(np.isfinite(transform)):
        return counts
    rows = _sample_rows(total, config)
    points = source.points[rows]
    moved = points @ transform[:3, :3].T + transform[:3, 3]
    distance, nearest = target.points_tree().query(
        moved, distance_upper_bound=config.overlap_distance
    )
    found = np.isfinite(distance)
    weight = _area_weights(points, config.range_exponent)[found] * len(rows)
    np.add.at(counts, (source.labels[rows][found], target.labels[nearest[found]]), weight)
    return counts


def self_cooccurrence(
    scan: PreparedScan, num_classes: int, config: VerificationConfig
) -> np.ndarray:
    """
    ``(C, C)`` counts of (label, label of the nearest other point) over a scan's own sample.

    The seeded sample and the range weights of :func:`cooccurrence` (normalised to a mean of
    1 per sampled point); the neighbour within ``overlap_distance``. What the labels of one
    scan say about themselves: the noise channel of a scan, seen twice.
    """
    counts = np.zeros((num_classes, num_classes))
    total = scan.points.shape[0]
    if total < 2:
        return counts
    rows = _sample_rows(total, config)
    points = scan.points[rows]
    distance, nearest = scan.points_tree().query(
        points, k=2, distance_upper_bound=config.overlap_distance
    )
    found = np.isfinite(distance[:, 1])
    weight = _area_weights(points, config.range_exponent)[found] * len(rows)
    np.add.at(counts, (scan.labels[rows][found], scan.labels[nearest[found, 1]]), weight)
    return counts


def confusion(counts: np.ndarray, counted: np.ndarray) -> np.ndarray:
    """
    Return the label confusion matrix ``P(target label b | source label a)`` of counts.

    ``counts``: ``(C, C)`` from :func:`cooccurrence` at a pose (its own dense
    correspondences: each sampled source point and its nearest target point). Rows and
    columns of classes that are not ``counted`` are zero, and so is a row never seen. At
    the right pose the matrix is the pair's label channel: a diagonal for clean labels,
    flattened by random flips, and a class swapped in one scan shows as its off-diagonal
    partner.
    """
    kept = np.asarray(counts, dtype=np.float64) * np.outer(counted, counted)
    rows = kept.sum(axis=1, keepdims=True)
    return np.divide(kept, rows, out=np.zeros_like(kept), where=rows > 0)


def information(counts: np.ndarray, compatibility: Any) -> float:
    """
    Label agreement beyond chance of co-occurrence counts (Cohen's kappa), NaN if none.

    ``kappa = (A - E) / (1 - E)``: ``A`` the (compatibility-weighted) share of agreeing
    counted pairs, ``E`` the agreement expected of labels independent of each other with
    the same class shares (the outer product of the two marginals). 1: every pair agrees;
    0: no more than chance (a street put on itself 40 m off still agrees on road and
    facades by chance: ``E`` is 0.2-0.5 on the dev pairs). Random flips shrink it by about
    the same factor for a pose and for a scan against itself (:func:`self_cooccurrence`),
    so :func:`information_ceiling` normalises it as the label ceiling normalises ``A``.
    """
    counted = compatibility.counted
    kept = np.asarray(counts, dtype=np.float64)[np.ix_(counted, counted)]
    total = kept.sum()
    if total <= 0:
        return float('nan')
    joint = kept / total
    weights = np.asarray(compatibility.compatible, dtype=np.float64)[np.ix_(counted, counted)]
    observed = float((joint * weights).sum())
    expected = float((np.outer(joint.sum(axis=1), joint.sum(axis=0)) * weights).sum())
    return (observed - expected) / (1.0 - expected) if expected < 1.0 else float('nan')


def information_ceiling(
    source: PreparedScan, target: PreparedScan, compatibility: Any, config: VerificationConfig
) -> float:
    """
    ``sqrt`` of both scans' :func:`information` with themselves; NaN if unknown or <= 0.

    KITTI dev pairs (``self_cooccurrence`` of each scan): 0.87-0.96 with the network's
    labels, 0.41-0.76 with 10 % flips, 0.14-0.46 with 30 %, 0.01-0.08 with 70 %; 0.39-0.61
    with 30 % confusions; 0.85-0.94 with the geometric labeler's (smooth within a scan
    whatever they are worth across scans).
    """
    count = len(compatibility.counted)
    a = information(self_cooccurrence(source, count, config), compatibility)
    b = information(self_cooccurrence(target, count, config), compatibility)
    return math.sqrt(a * b) if a > 0 and b > 0 else float('nan')


def distinctive_self_agreement(
    scan: PreparedScan, distinctive: np.ndarray, distance: float
) -> float:
    """
    Share of the scan's distinctive-class points whose nearest other point is one too.

    ``distinctive``: ``(C,)`` bool over learning ids (``confidence.distinctive_classes``).
    The label self-agreement (:func:`self_agreement`) of the classes the distinctive objects
    are made of: a pole's points lie next to pole points, a point flipped to "pole" on a
    wall lies next to wall points. Neighbours within ``distance``; NaN with fewer than two
    distinctive points or no neighbour.
    """
    labels = np.asarray(scan.labels, dtype=np.int64)
    known = (labels >= 0) & (labels < distinctive.size)
    marked = known & distinctive[np.where(known, labels, 0)]
    if marked.sum() < 2:
        return float('nan')
    found, nearest = scan.points_tree().query(
        scan.points[marked], k=2, distance_upper_bound=distance
    )
    seen = np.isfinite(found[:, 1])
    if not seen.any():
        return float('nan')
    return float(marked[nearest[seen, 1]].mean())


def distinctive_ceiling(
    source: PreparedScan, target: PreparedScan, distinctive: np.ndarray, distance: float
) -> float:
    """
    ``sqrt`` of both scans' :func:`distinctive_self_agreement`; NaN if unknown.

    How far the distinctive objects (poles, signs, trunks: ``confidence.distinctive_*``)
    can be trusted. Dev pairs and their 40 m compositions: 0.65-0.96 with the given labels
    and with 30-50 % confusions (they leave these classes alone), 0.06-0.34 with 10-30 %
    of the labels flipped (flipped points of these classes lie on walls and road).
    """
    a = distinctive_self_agreement(source, distinctive, distance)
    b = distinctive_self_agreement(target, distinctive, distance)
    return math.sqrt(a * b) if a >= 0 and b >= 0 else float('nan')


class LabelModel:
    """
    Class compatibility learned from the label co-occurrence at accepted poses.

    ``prior``: the fixed ``(C, C)`` compatibility (boolean rules of
    ``verification.compatible_classes``); learned weights only add to it. ``decay``: each
    :meth:`update` first multiplies the counts by it (``1``: never forget).
    ``min_association``: ``r0`` of the module docstring. ``min_count``: a class pair is
    judged only when both classes have at least that much weight on the diagonal.
    """

    def __init__(
        self,
        prior: np.ndarray,
        *,
        decay: float = 0.98,
        min_association: float = 0.15,
        min_count: float = 200.0,
    ) -> None:
        self.prior = np.asarray(prior, dtype=np.float64)
        self.decay = float(decay)
        self.min_association = float(min_association)
        self.min_count = float(min_count)
        self.counts = np.zeros_like(self.prior)
        self.updates = 0

    @classmethod
    def from_config(cls, prior: np.ndarray, config: ConfidenceConfig) -> LabelModel:
        """Build a model with the ``confidence.label_*`` settings."""
        return cls(
            prior,
            decay=config.label_decay,
            min_association=config.label_min_association,
            min_count=config.label_min_count,
        )

    def update(self, counts: np.ndarray) -> None:
        """Add one accepted pose's ``(C, C)`` co-occurrence counts (:func:`cooccurrence`)."""
        counts = np.asarray(counts, dtype=np.float64)
        if counts.shape != self.counts.shape or not np.all(np.isfinite(counts)):
            raise ValueError(
                f'co-occurrence counts must be finite {self.counts.shape}, got {counts.shape}'
            )
        self.counts = self.decay * self.counts + np.clip(counts, 0.0, None)
        self.updates += 1

    def association(self) -> np.ndarray:
        """``r(a, b) = max(N(a, b) / N(a, a), N(b, a) / N(b, b))``, 1 on the diagonal."""
        diag = np.diag(self.counts)
        enough = diag >= self.min_count
        rate = np.where(
            enough[:, None], self.counts / np.maximum(diag, 1e-300)[:, None], 0.0
        )  # a as b per a as a (rows: source labels)
        r = np.maximum(rate, rate.T) * np.outer(enough, enough)
        np.fill_diagonal(r, 1.0)
        return r

    def learned(self) -> np.ndarray:
        """Return the learned weights ``w(a, b)`` in ``[0, 1]`` (module docstring)."""
        r0 = self.min_association
        return np.clip((self.association() - r0) / max(1.0 - r0, 1e-9), 0.0, 1.0)

    def compatibility(self) -> np.ndarray:
        """``(C, C)`` float weights for the label agreement: max of the prior and learned."""
        return np.maximum(self.prior, self.learned())

    def confused_pairs(self, names: tuple[str, ...], threshold: float = 0.5) -> list[str]:
        """Learned pairs ``a~b`` with weight above ``threshold`` (not in the prior)."""
        w = self.learned()
        a, b = np.nonzero(np.triu(w > threshold, k=1) & ~np.triu(self.prior > 0, k=1))
        return [f'{names[i]}~{names[j]}' for i, j in zip(a.tolist(), b.tolist(), strict=True)]
