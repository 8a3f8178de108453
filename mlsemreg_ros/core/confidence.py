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
  scores it, :func:`mlsemreg_ros.core.verification.dense_scores`): at least
  ``confidence.min_overlap`` of the seen surface of the source scan lies on the target
  scan, and at least ``confidence.min_label_agreement`` of those overlapping points
  carry the same (or a compatible) label;
- **plausible**: the pose turns the up axis by at most ``confidence.max_tilt`` (a ground
  vehicle does not roll over between scans; a mirrored cloud fits best upside down).

GM-only results (no usable landmark) face the same rule. The thresholds come from the
distributions measured by ``mlsemreg-confidence`` (correct and wrong registrations of
the dev pairs, non-overlapping chain pairs, mirrored clouds, label-corrupted scans and
simulated drives; docs/results.md shows them).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from mlsemreg_ros.core.config import ConfidenceConfig
from mlsemreg_ros.core.label_model import label_refusal
import numpy as np


@dataclass(frozen=True)
class Evidence:
    """What one registration offers as proof of being right."""

    num_inliers: int  # sparse inliers of the chosen pose
    correspondences: int
    overlap: float  # share of the source scan's seen surface on the target scan
    label_agreement: float  # share of the overlapping labeled points that agree
    tilt_deg: float  # angle between the two scans' up axes under the chosen pose
    #: label agreement these labels can give (core/label_model.py); NaN: unknown
    label_ceiling: float = float('nan')

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


def tilt_deg(transform: np.ndarray) -> float:
    """Angle (deg) between the target's z axis and the source's z axis under ``transform``."""
    cos = float(np.clip(np.asarray(transform, dtype=np.float64)[2, 2], -1.0, 1.0))
    return float(np.degrees(np.arccos(cos))) if np.isfinite(cos) else float('nan')


def refusal(evidence: Evidence, config: ConfidenceConfig, min_inliers: int) -> str:
    """Why the evidence is not enough ('' when the registration is accepted)."""
    reasons = []
    if evidence.num_inliers < min_inliers:
        reasons.append(f'{evidence.num_inliers} inliers < estimator.min_inliers={min_inliers}')
    if evidence.inlier_ratio < config.min_inlier_ratio:
        reasons.append(
            f'inlier ratio {evidence.inlier_ratio:.4f} < '
            f'confidence.min_inlier_ratio={config.min_inlier_ratio:g}'
        )
    if evidence.overlap < config.min_overlap:
        reasons.append(
            f'overlap {evidence.overlap:.3f} < confidence.min_overlap={config.min_overlap:g}'
        )
    label = label_refusal(evidence.label_agreement, evidence.label_ceiling, config)
    if label:
        reasons.append(label)
    if not evidence.tilt_deg <= config.max_tilt:  # NaN fails too
        reasons.append(
            f'tilt {evidence.tilt_deg:.1f} deg > confidence.max_tilt={config.max_tilt:g} deg'
        )
    return '; '.join(reasons)
