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
Registration confidence: whether the evidence of a registration says it is right.

SC2-PCR's inlier count alone is not enough: two scans that do not overlap at all still
give 11-50 "inliers" of ~2600 correspondences by chance, and a cloud mirrored in y gave
483. A registration is therefore accepted only when every kind of evidence agrees:

- **sparse**: at least ``estimator.min_inliers`` inliers and an inlier ratio (inliers /
  correspondences) of at least ``confidence.min_inlier_ratio``;
- **dense** (the chosen pose applied to the voxelized scans, as hypothesis verification
  scores it, :func:`mlsemreg_ros.core.estimation.verification.dense_scores`): at least
  ``confidence.min_overlap`` of the seen surface of the source scan lies on the target
  scan, and at least ``confidence.min_label_agreement`` of those overlapping points
  carry the same (or a compatible) label;
- **plausible**: the pose turns the up axis by at most ``confidence.max_tilt`` (a ground
  vehicle does not roll over between scans; a mirrored cloud fits best upside down).

- **unambiguous** (docs/hard_pairs.md): no *rival* pose explains the scans about as well.
  Rivals are the other candidates (the estimator's verified hypotheses and, when it ran,
  the BEV search's peaks) that are distinct from the chosen pose by more than
  ``confidence.rival_translation`` / ``confidence.rival_rotation``, the zero-motion pose
  (the scans on top of each other) and the chosen pose slid by ``confidence.slide_distance``
  along eight horizontal directions (a straight street: road, curbs and facades line up
  at any slide). A rival within ``confidence.ambiguity_margin`` of the chosen pose's
  verification score makes the registration ambiguous, unless the **distinctive
  structure** decides: the chosen pose puts at least ``confidence.min_distinctive_objects``
  objects of ``confidence.distinctive_classes`` (poles, signs, trunks: things that pin a
  place down) of the source on such target points, at least
  ``confidence.min_distinctive_fraction`` of those that land in the target's view (the
  others contradict the pose) and either more objects than any close rival or at least
  ``confidence.distinctive_gain`` times the share of distinctive points it lines up;
- **not contradicted**: a pose that puts at least ``confidence.contradicting_objects``
  distinctive source objects in the target's view and lines up fewer than
  ``confidence.contradicted_fraction`` of them is refused
  (a flip of a symmetric street, a slide: their poles land beside the target's), as long
  as the labels' ceiling reaches ``confidence.contradiction_min_ceiling`` and the
  distinctive classes' labels are clean enough (noisy labels make objects of mislabeled
  points, :func:`labels_clean_enough`, :func:`objects_trusted`; nor do flipped labels'
  objects decide an ambiguity or choose a candidate); below
  ``confidence.min_label_ceiling`` the labels vouch for no pose at all;
- **well constrained** (after the fine alignment, :func:`localizability`): the
  alignment's Gauss-Newton Hessian constrains every translation direction (Zhang et al.
  2016, "On degeneracy of optimization-based state estimation problems"); a weak
  direction is reported, and ``confidence.degeneracy`` says whether it is only reported,
  inflates the covariance along it or refuses the registration.

GM-only results (no usable landmark) face the same rule. The thresholds come from the
distributions measured by ``mlsemreg-confidence`` (correct and wrong registrations of
the dev pairs, non-overlapping chain pairs, mirrored clouds, label-corrupted scans and
simulated drives; docs/results.md shows them).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from mlsemreg_ros.core.estimation.chance import required_inliers
from mlsemreg_ros.core.estimation.config import ConfidenceConfig
from mlsemreg_ros.core.estimation.label_model import label_refusal
import numpy as np


@dataclass(frozen=True)
class Evidence:
    """What one registration offers as proof of being right."""

    num_inliers: int  # sparse inliers of the chosen pose
    correspondences: int
    overlap: float  # share of the source scan's seen surface on the target scan
    label_agreement: float  # share of the overlapping labeled points that agree
    tilt_deg: float  # angle between the two scans' up axes under the chosen pose
    score: float = 0.0  # verification score of the chosen pose
    distinctive_objects: int = 0  # distinctive source objects lined up (poles, trunks)
    distinctive_in_view: int = 0  # distinctive source objects that land in the target's view
    distinctive_overlap: float = 0.0  # their share of the source's distinctive points
    rival_score: float = 0.0  # best score of a rival pose (0: no rival scored)
    rival_distinctive_overlap: float = 0.0  # largest distinctive share of a close rival
    rival: str = ''  # what the best rival is (e.g. 'zero motion', 'slide 5 m', 'bev_search')
    rival_distinctive_objects: int = 0  # most distinctive objects a close rival lines up
    #: label agreement these labels can give (core/estimation/label_model.py); NaN: unknown
    label_ceiling: float = float('nan')
    #: the same for the distinctive classes only (label_model.distinctive_ceiling); NaN: unknown
    distinctive_ceiling: float = float('nan')
    #: agreement beyond chance at the pose (label_model.information); NaN: not measured
    label_information: float = float('nan')
    #: what the labels give against themselves (label_model.information_ceiling); NaN: unknown
    information_ceiling: float = float('nan')
    #: largest consensus the estimator won on re-paired correspondences (chance.py); NaN: none
    chance_inliers: float = float('nan')

    @property
    def inlier_ratio(self) -> float:
        """Sparse inliers / correspondences (0 without correspondences)."""
        return self.num_inliers / self.correspondences if self.correspondences else 0.0

    def as_diagnostics(self) -> dict[str, float]:
        """Flat values for the result's diagnostics (``confidence_*``)."""
        return {
            f'confidence_{k}': v
            for k, v in {**asdict(self), 'inlier_ratio': self.inlier_ratio}.items()
        }

    def ambiguity(self, config: ConfidenceConfig) -> str:
        """Why a rival makes the chosen pose ambiguous ('' when it does not)."""
        if self.rival_score <= 0.0 or self.rival_score < (1.0 - config.ambiguity_margin) * (
            self.score
        ):
            return ''
        decided = (
            objects_trusted(self.distinctive_ceiling, config)
            and self.distinctive_objects >= config.min_distinctive_objects
            and self.distinctive_objects
            >= config.min_distinctive_fraction * self.distinctive_in_view
            and (
                self.distinctive_overlap
                >= config.distinctive_gain * self.rival_distinctive_overlap
                or self.distinctive_objects > self.rival_distinctive_objects
            )
        )
        if decided:
            return ''
        return (
            f'ambiguous: {self.rival or "a rival pose"} scores {self.rival_score:.3f} '
            f'against {self.score:.3f} (within confidence.ambiguity_margin='
            f'{config.ambiguity_margin:g}) and the distinctive structure does not decide '
            f'({self.distinctive_objects} of {self.distinctive_in_view} objects in view lined '
            f'up, share {self.distinctive_overlap:.3f} vs '
            f'{self.rival_distinctive_overlap:.3f}; confidence.min_distinctive_objects='
            f'{config.min_distinctive_objects}, min_distinctive_fraction='
            f'{config.min_distinctive_fraction:g}, distinctive_gain={config.distinctive_gain:g})'
        )


def tilt_deg(transform: np.ndarray) -> float:
    """Angle (deg) between the target's z axis and the source's z axis under ``transform``."""
    cos = float(np.clip(np.asarray(transform, dtype=np.float64)[2, 2], -1.0, 1.0))
    return float(np.degrees(np.arccos(cos))) if np.isfinite(cos) else float('nan')


def objects_trusted(distinctive_ceiling: float, config: ConfidenceConfig) -> bool:
    """
    Whether the distinctive objects count: the labels of their classes are clean enough.

    With flipped labels, scattered points of ``confidence.distinctive_classes`` on walls
    and road form "objects" that line up by chance: with 10 % flips, a pose of FPFH dev
    pair 000008 4.7 m off lined up 2 of 4 objects and replaced the right pose, which scored
    1.4 times higher and lined up 1 of 6 (docs/label_noise.md). The
    ``distinctive_ceiling``
    (:func:`~mlsemreg_ros.core.estimation.label_model.distinctive_ceiling`) measures the
    labels of exactly those classes: 0.65-0.96 on the dev pairs and their 40/60 m
    compositions, also under confusions of other classes, 0.06-0.34 with 10-30 % flips,
    about 0.6-0.7 per scan with the simulated network labels of the field drives. Below
    ``confidence.min_distinctive_ceiling`` the objects neither choose among the candidates
    (``_Pool.decide`` in ``core/pipeline.py``), nor decide an ambiguity
    (:meth:`Evidence.ambiguity`), nor contradict a pose (:func:`labels_clean_enough`): the
    verification score alone decides. Unknown (NaN) or the parameter 0: they count.
    """
    return not (
        config.min_distinctive_ceiling > 0
        and np.isfinite(distinctive_ceiling)
        and distinctive_ceiling < config.min_distinctive_ceiling
    )


def labels_clean_enough(evidence: Evidence, config: ConfidenceConfig) -> bool:
    """
    Whether the labels are clean enough for the contradiction check (docs/label_noise.md).

    With noisy labels, mislabeled points of ``confidence.distinctive_classes`` on walls and
    road form source "objects" that land in the target's view and cannot line up: with 20 %
    of the source labels random, the right dev poses put 8-31 objects in view and line up
    1-6 of them. Their label ceiling
    (:func:`~mlsemreg_ros.core.estimation.label_model.label_ceiling`) says so: 0.74-0.81
    there, at least 0.90 on the clean dev pairs. Below
    ``confidence.contradiction_min_ceiling`` the check is skipped (an unknown, NaN,
    ceiling keeps it), and so it is while the objects are not trusted
    (:func:`objects_trusted`).
    """
    ceiling = evidence.label_ceiling
    clean = not (np.isfinite(ceiling) and ceiling < config.contradiction_min_ceiling)
    return clean and objects_trusted(evidence.distinctive_ceiling, config)


def refusal(evidence: Evidence, config: ConfidenceConfig, min_inliers: int) -> str:
    """Why the evidence is not enough ('' when the registration is accepted)."""
    reasons = []
    required = required_inliers(evidence.chance_inliers, config, min_inliers)
    by_chance = config.count_rule == 'chance' and np.isfinite(evidence.chance_inliers)
    if evidence.num_inliers < required:
        if by_chance:
            reasons.append(
                f'{evidence.num_inliers} inliers < {required:g}: confidence.chance_margin='
                f'{config.chance_margin:g} x {evidence.chance_inliers:g} won by chance '
                f'(confidence.chance_floor={config.chance_floor})'
            )
        else:
            reasons.append(f'{evidence.num_inliers} inliers < estimator.min_inliers={min_inliers}')
    if not by_chance and evidence.inlier_ratio < config.min_inlier_ratio:  # chance: replaced
        reasons.append(
            f'inlier ratio {evidence.inlier_ratio:.4f} < '
            f'confidence.min_inlier_ratio={config.min_inlier_ratio:g}'
        )
    if evidence.overlap < config.min_overlap:
        reasons.append(
            f'overlap {evidence.overlap:.3f} < confidence.min_overlap={config.min_overlap:g}'
        )
    ceiling = evidence.label_ceiling
    information = config.label_rule == 'information'  # poorer labels: replaces the ceiling
    if not information and np.isfinite(ceiling) and ceiling < config.min_label_ceiling:
        reasons.append(
            f'label ceiling {ceiling:.2f} < confidence.min_label_ceiling='
            f'{config.min_label_ceiling:g}: the labels are too noisy to vouch for a pose'
        )
    label = label_refusal(
        evidence.label_agreement,
        evidence.label_ceiling,
        config,
        evidence.label_information,
        evidence.information_ceiling,
    )
    if label:
        reasons.append(label)
    if not evidence.tilt_deg <= config.max_tilt:  # NaN fails too
        reasons.append(
            f'tilt {evidence.tilt_deg:.1f} deg > confidence.max_tilt={config.max_tilt:g} deg'
        )
    contradicted = (
        config.contradicting_objects > 0
        and labels_clean_enough(evidence, config)
        and evidence.distinctive_objects
        < config.contradicted_fraction * evidence.distinctive_in_view
    )
    if contradicted and evidence.distinctive_in_view >= config.contradicting_objects:
        reasons.append(
            f'contradicted: {evidence.distinctive_in_view} distinctive objects land in the '
            f'target view, {evidence.distinctive_objects} on distinctive target points '
            f'(confidence.contradicting_objects={config.contradicting_objects}, '
            f'contradicted_fraction={config.contradicted_fraction:g})'
        )
    ambiguous = evidence.ambiguity(config)
    if ambiguous:
        reasons.append(ambiguous)
    return '; '.join(reasons)


def slid_poses(transform: np.ndarray, distance: float, directions: int = 8) -> np.ndarray:
    """
    Move ``transform`` by ``distance`` along evenly spread horizontal directions.

    Returns ``(directions, 4, 4)`` poses, directions in the target frame: the rivals of a
    pose on a straight street.
    """
    angles = np.arange(directions) * (2.0 * np.pi / directions)
    poses = np.repeat(np.asarray(transform, dtype=np.float64)[None], directions, axis=0)
    poses[:, 0, 3] += distance * np.cos(angles)
    poses[:, 1, 3] += distance * np.sin(angles)
    return poses


@dataclass(frozen=True)
class Localizability:
    """How well a fine alignment's Hessian constrains the translation (Zhang et al. 2016)."""

    eigenvalues: np.ndarray  # (3,) ascending, of the translation block of H
    weak_direction: np.ndarray  # (3,) unit, target frame: the eigenvector of the smallest
    ratio: float  # smallest / largest eigenvalue (1: isotropic, 0: unconstrained)

    def as_diagnostics(self) -> dict[str, float | str]:
        """Flat values for the result's diagnostics (``degeneracy_*``)."""
        x, y, z = (float(v) for v in self.weak_direction)
        return {
            'degeneracy_ratio': self.ratio,
            'degeneracy_weak_direction': f'{x:+.2f} {y:+.2f} {z:+.2f}',
            'degeneracy_eigenvalues': ' '.join(f'{v:.4g}' for v in self.eigenvalues),
        }


def localizability(hessian: np.ndarray, rotation: np.ndarray) -> Localizability | None:
    """
    Eigen-analysis of the translation block of small_gicp's Hessian (order [omega, v]).

    The eigenvector of the smallest eigenvalue is the direction the scans constrain least
    (a corridor: along it); ``rotation`` (the alignment's ``R_target_source``) turns it into
    the target frame. None when the Hessian is not finite.
    """
    H = np.asarray(hessian, dtype=np.float64)
    if H.shape != (6, 6) or not np.all(np.isfinite(H)):
        return None
    values, vectors = np.linalg.eigh(0.5 * (H[3:, 3:] + H[3:, 3:].T))
    values = np.clip(values, 0.0, None)
    weak = np.asarray(rotation, dtype=np.float64) @ vectors[:, 0]
    weak = weak * (1.0 if weak[np.argmax(np.abs(weak))] >= 0 else -1.0)  # sign: largest +
    ratio = float(values[0] / values[-1]) if values[-1] > 0 else 0.0
    return Localizability(values, weak, ratio)


def inflated_hessian(hessian: np.ndarray, factor: float) -> np.ndarray:
    """
    ``hessian`` with the smallest eigenvalue of its translation block divided by ``factor``.

    Every covariance derived from it (``inv(H)``) grows by ``factor`` along the weak
    direction and is unchanged across it.
    """
    H = np.array(hessian, dtype=np.float64)
    values, vectors = np.linalg.eigh(0.5 * (H[3:, 3:] + H[3:, 3:].T))
    weak = vectors[:, :1]
    H[3:, 3:] -= (1.0 - 1.0 / factor) * values[0] * (weak @ weak.T)
    return H


def degeneracy_refusal(found: Localizability | None, config: ConfidenceConfig) -> str:
    """Why the alignment is degenerate ('' when it is not or ``degeneracy`` is not refuse)."""
    if found is None or config.degeneracy != 'refuse' or found.ratio >= config.min_localizability:
        return ''
    x, y, z = found.weak_direction
    return (
        f'degenerate: translation along ({x:+.2f}, {y:+.2f}, {z:+.2f}) constrained '
        f'{found.ratio:.2g} as well as the best direction < confidence.min_localizability='
        f'{config.min_localizability:g}'
    )
