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

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.deferred import deferred_attribute
import numpy as np
from scipy.spatial import cKDTree

if TYPE_CHECKING:  # small_gicp is only needed where the fine alignment runs
    from mlsemreg_ros.core.alignment.alignment import Alignment, AlignmentCloud


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
    labels: np.ndarray  # (N,) int32 learning ids (may be given as a Deferred: core/deferred.py)
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
    #: KD-tree of ``points`` (built by :meth:`Registration.prepare`, or on first use)
    kdtree: cKDTree | None = field(default=None, repr=False, compare=False)
    #: what a lazy :meth:`Registration.prepare` left out (descriptors, signatures, landmarks,
    #: KD-tree); :meth:`Registration.complete` runs it once
    pending_features: Callable[[PreparedScan], None] | None = field(
        default=None, repr=False, compare=False
    )
    #: (N,) bool: points the odometry keeps out of its local map and fine alignment (moving
    #: objects, ``core/features/moving_objects.py``); None: none
    map_excluded: np.ndarray | None = field(default=None, repr=False, compare=False)

    def points_tree(self) -> cKDTree:
        """
        KD-tree of ``points``, built on first use and kept with the scan.

        Hypothesis verification queries the target scan once per registration; a node
        registers many scans against one keyframe, so the tree is built once per keyframe.
        """
        if self.kdtree is None:
            self.kdtree = self.build_points_tree(self.points)
        return self.kdtree

    @staticmethod
    def build_points_tree(points: np.ndarray) -> cKDTree:
        """KD-tree of a scan: sliding-midpoint splits, no node shrinking (~40 % cheaper)."""
        return cKDTree(points, balanced_tree=False, compact_nodes=False)


deferred_attribute(PreparedScan, 'labels')


@dataclass
class Correspondences:
    """Putative matches between source and target keypoints."""

    source: np.ndarray  # (K,) int64 rows of the source keypoints
    target: np.ndarray  # (K,) int64 rows of the target keypoints
    distance: np.ndarray  # (K,) float32 descriptor distance

    def __len__(self) -> int:
        return int(self.source.shape[0])


@dataclass
class Hypotheses:
    """
    Every rigid-transform hypothesis of an estimator, most inliers first.

    SC2-PCR (Chen et al., CVPR 2022) makes one hypothesis per seed and keeps the one with
    most inliers; the others are the candidates of hypothesis verification.
    """

    T_target_source: np.ndarray  # (S, 4, 4) before post-refinement
    num_inliers: np.ndarray  # (S,) int64 correspondences with residual < inlier_threshold

    def __len__(self) -> int:
        return int(self.num_inliers.shape[0])


@dataclass
class EstimateResult:
    """Output of a robust estimator."""

    transform: np.ndarray  # (4, 4) T_target_source: p_target = T @ p_source
    inlier_mask: np.ndarray  # (K,) bool, residual < inlier_threshold under transform
    diagnostics: dict[str, Any] = field(default_factory=dict)
    hypotheses: Hypotheses | None = None  # all candidates (SC2-PCR), hypotheses[0] -> transform

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


@dataclass
class HypothesisScore:
    """One verified hypothesis: its refined transform and its scores on the dense scans."""

    T_target_source: np.ndarray  # (4, 4) after the estimator's post-refinement
    rank: int  # position in its origin's list (estimator: 0 is its own choice)
    num_inliers: int  # correspondences with residual < estimator.inlier_threshold
    overlap: float  # share of sampled source points within overlap_distance of the target
    label_agreement: float  # share of the overlapping labeled points with compatible labels
    score: float  # combined score, see core/estimation/verification.py
    origin: str = 'estimator'  # where the pose came from: 'estimator' or 'bev_search'


@dataclass
class VerificationResult:
    """Outcome of hypothesis verification: every candidate's scores and the choice."""

    hypotheses: list[HypothesisScore]  # hypotheses[0] is the estimator's choice
    chosen: int  # index into hypotheses
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def T_target_source(self) -> np.ndarray:
        """Transform of the chosen hypothesis."""
        return self.hypotheses[self.chosen].T_target_source

    @property
    def switched(self) -> bool:
        """Whether verification overruled the estimator's choice."""
        return self.chosen != 0
