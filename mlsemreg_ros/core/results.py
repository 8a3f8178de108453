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

"""Result objects passed between the stages of the core."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # small_gicp is only needed where the fine alignment runs
    from mlsemreg_ros.core.alignment import Alignment, AlignmentCloud


@dataclass
class Landmarks:
    """BMR-SS landmarks of one scan: cluster centroids and their learning ids."""

    centroids: np.ndarray  # (Z, 3) float64, metres
    classes: np.ndarray  # (Z,) int64 learning ids

    @classmethod
    def empty(cls) -> Landmarks:
        """No landmark."""
        return cls(np.zeros((0, 3)), np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return int(self.classes.shape[0])

    def counts(self) -> dict[int, int]:
        """Landmarks per learning id."""
        ids, counts = np.unique(self.classes, return_counts=True)
        return {int(i): int(c) for i, c in zip(ids, counts, strict=True)}


@dataclass
class PreparedScan:
    """
    A scan with everything registration needs, computed once and cacheable.

    Keypoints with non-finite or all-zero descriptors are already dropped.
    """

    points: np.ndarray  # (N, 3) float64 downsampled scan, sensor frame, metres
    labels: np.ndarray  # (N,) int32 learning ids
    keypoints: np.ndarray  # (M, 3) float64
    keypoint_indices: np.ndarray  # (M,) int64 rows of points (-1 if given externally)
    descriptors: np.ndarray  # (M, D) float32
    local_ss: np.ndarray  # (M, C) bool: Local Semantic Signature, C = number of classes
    landmarks: Landmarks
    timings_ms: dict[str, float] = field(default_factory=dict)
    #: small_gicp clouds of the fine alignment by (downsampling resolution m, neighbours)
    alignment_clouds: dict[tuple[float, int], AlignmentCloud] = field(default_factory=dict)
    #: what the input hygiene did: dropped points by kind, label scheme, out-of-scheme labels
    input_stats: dict[str, Any] = field(default_factory=dict)


@dataclass
class Correspondences:
    """Putative matches between source and target keypoints."""

    source: np.ndarray  # (K,) int64 rows of the source keypoints
    target: np.ndarray  # (K,) int64 rows of the target keypoints
    distance: np.ndarray  # (K,) float32 descriptor distance

    def __len__(self) -> int:
        return int(self.source.shape[0])


@dataclass
class EstimateResult:
    """Output of a robust estimator."""

    transform: np.ndarray  # (4, 4) T_target_source: p_target = T @ p_source
    inlier_mask: np.ndarray  # (K,) bool, residual < inlier_threshold under transform
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def num_inliers(self) -> int:
        """Correspondences consistent with the estimate."""
        return int(np.count_nonzero(self.inlier_mask))


@dataclass
class RegistrationResult:
    """Everything one pairwise registration produces."""

    transform: np.ndarray  # (4, 4) T_target_source: p_target = T @ p_source (final)
    correspondences: Correspondences
    source_points: np.ndarray  # (K, 3) source keypoints of the correspondences
    target_points: np.ndarray  # (K, 3) target keypoints of the correspondences
    inlier_mask: np.ndarray  # (K,) bool
    success: bool  # enough inliers (estimator.min_inliers) under the estimate
    mode: str  # 'ml-semreg', 'gm-only' (no usable landmark) or 'plain'
    message: str = ''  # why a fallback or a failure happened
    timings_ms: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    estimate: np.ndarray | None = None  # (4, 4) the estimator's T_target_source
    alignment: Alignment | None = None  # the fine alignment, when it ran

    @property
    def num_inliers(self) -> int:
        """Correspondences consistent with the estimate."""
        return int(np.count_nonzero(self.inlier_mask))
