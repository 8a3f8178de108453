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
The refused path: the stages after a refused BEV search, and the check of a refused refinement.

The registration's refused-path stages (``core/stages/refused_path.py``) run them when the
confidence rule still refuses the pose after the BEV search (core/estimation/bev_search.py),
cheapest first (docs/hard_pairs.md): guided re-matching around the best searched peaks
(core/estimation/guided.py), SC2-PCR again on the full correspondence graph, and the
polishing of the pool's best candidates on the dense scans (core/estimation/polish.py).
Every stage returns verified candidates that join the registration's pool.
:meth:`RefusedPath.refinement_holds` tells whether a fine alignment refused by its bounds
still keeps the dense score (at 40-60 m the true overlap stays under
``odometry.min_inlier_fraction``).
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
from dataclasses import dataclass
from typing import Any, Protocol, TYPE_CHECKING

from mlsemreg_ros.core.alignment.alignment import align_pair
from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud
from mlsemreg_ros.core.estimation.estimation import estimate
from mlsemreg_ros.core.estimation.guided import guided_correspondences
from mlsemreg_ros.core.estimation.polish import polish_poses, radius_schedule
from mlsemreg_ros.core.estimation.verification import (
    combined_score,
    LabelCompatibility,
    score_hypotheses,
)
from mlsemreg_ros.core.poses import distinct_hypotheses
from mlsemreg_ros.core.results import (
    EstimateResult,
    HypothesisScore,
    PreparedScan,
    VerificationResult,
)
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig

#: ``verify(estimated, src_pts, dst_pts, source, target)``: the registration's verification.
Verify = Callable[
    [EstimateResult, np.ndarray, np.ndarray, PreparedScan, PreparedScan], VerificationResult
]
#: ``dense(transforms, source, target)``: ``(overlap, label agreement)`` of (N, 4, 4) poses.
Dense = Callable[[np.ndarray, PreparedScan, PreparedScan], tuple[np.ndarray, np.ndarray]]


class Candidates(Protocol):
    """The registration's pool of verified candidates, as the polishing reads it."""

    points: np.ndarray  # (N,) distinctive objects lined up

    def transforms(self) -> np.ndarray:
        """``(N, 4, 4)`` candidate poses."""

    def scores(self) -> np.ndarray:
        """``(N,)`` verification scores."""


@dataclass(frozen=True)
class RefusedPath:
    """
    The refused-path stages of one registration configuration.

    ``verify`` and ``dense`` are the registration's own verification and dense scores
    (the same configuration and label compatibility), so a stage scores its candidates
    exactly as the rest of the registration does.
    """

    config: RegistrationConfig
    compatibility: LabelCompatibility
    verify: Verify
    dense: Dense

    def full_graph(
        self,
        source: PreparedScan,
        target: PreparedScan,
        src_pts: np.ndarray,
        dst_pts: np.ndarray,
        diagnostics: dict[str, Any],
    ) -> VerificationResult:
        """
        SC2-PCR again on every correspondence (no ``estimator.graph_size`` sample), verified.

        At 60 m a pair can hold 79 true correspondences in 7657 (1 %): a sample of 500
        keeps five, too few to seed, while its best wrong hypothesis has enough inliers
        (66) to skip ``estimator.graph_retry_inliers``. Origin ``'full_graph'``.
        """
        cfg = self.config
        estimated = estimate(src_pts, dst_pts, dataclasses.replace(cfg.estimator, graph_size=0))
        diagnostics['full_graph_inliers'] = estimated.num_inliers
        verified = self.verify(estimated, src_pts, dst_pts, source, target)
        hypotheses = [dataclasses.replace(h, origin='full_graph') for h in verified.hypotheses]
        return VerificationResult(hypotheses, verified.chosen)

    def polished(
        self,
        source: PreparedScan,
        target: PreparedScan,
        src_pts: np.ndarray,
        dst_pts: np.ndarray,
        pool: Candidates,
        refine: bool = True,
    ) -> VerificationResult:
        """
        Polish the pool's best candidates on the dense scans and score them (origin 'polished').

        The ``bev_search.polish_candidates`` best distinct candidates by score and every
        candidate lining up ``confidence.min_distinctive_objects``; each gets
        ``bev_search.polish_iterations`` point-to-point ICP steps
        (core/estimation/polish.py). With ``refine`` (the pair's fine alignment follows), the
        ``bev_search.polish_fine`` best distinct candidates also get that fine alignment.
        """
        cfg = self.config
        search, check = cfg.bev_search, cfg.verification
        transforms, scores = pool.transforms(), pool.scores()
        order = np.argsort(-scores, kind='stable')
        best = order[
            distinct_hypotheses(
                transforms[order],
                search.polish_candidates,
                check.distinct_rotation,
                check.distinct_translation,
            )
        ]
        lined_up = np.flatnonzero(pool.points >= cfg.confidence.min_distinctive_objects)
        chosen = np.union1d(best, lined_up)
        rng = np.random.default_rng(check.seed)
        count = len(source.points)
        rows = (
            rng.choice(count, search.polish_points, replace=False)
            if count > search.polish_points
            else np.arange(count)
        )
        polished = polish_poses(
            transforms[chosen],
            source.points[rows],
            target.points_tree(),
            target.points,
            radius_schedule(
                search.polish_radius, check.overlap_distance, search.polish_iterations
            ),
        )
        if refine and search.polish_fine > 0 and cfg.fine.pair_method != 'off':
            # the best few (polished or not) get the pair's fine alignment: a 6-DoF GICP
            # corrects the tilt the polishing leaves (60 m dev pair 000008_000010: 4.0 deg
            # -> 1.7 deg, and it outscores the flip it lost to)
            # the pool's candidates were scored on these scans already: only the polished
            # poses are scored here
            every = np.concatenate([transforms, polished])
            fresh = combined_score(*self.dense(polished, source, target), check)
            order = np.argsort(-np.concatenate([scores, fresh]))
            best = order[
                distinct_hypotheses(
                    every[order],
                    search.polish_fine,
                    check.distinct_rotation,
                    check.distinct_translation,
                )
            ]
            aligned = [
                align_pair(
                    alignment_cloud(source, cfg.fine),  # downsampled: a third of the time
                    alignment_cloud(target, cfg.fine, pair=True),
                    every[i],
                    cfg.fine,
                    cfg.fine.pair_method,
                ).T_target_source
                for i in best
            ]
            aligned = [T for T in aligned if np.all(np.isfinite(T))]
            if aligned:
                polished = np.concatenate([polished, np.stack(aligned)])
                chosen = np.concatenate([chosen, best[: len(aligned)]])
        return score_hypotheses(
            polished,
            chosen,
            src_pts,
            dst_pts,
            source,
            target,
            dataclasses.replace(check, min_gain=0.0),
            cfg.estimator,
            self.compatibility,
            origin='polished',
        )

    def guided(
        self,
        source: PreparedScan,
        target: PreparedScan,
        searched: VerificationResult,
        diagnostics: dict[str, Any],
    ) -> VerificationResult | None:
        """
        Guided re-matching around the ``bev_search.guided_peaks`` best searched poses.

        For each, correspondences only within ``bev_search.guided_radius`` of where the pose
        puts a source keypoint (compatible labels), then the estimator and the verification
        again (core/estimation/guided.py). Returns their verified hypotheses (origin ``'guided'``),
        None when no peak gave three correspondences. Adds ``guided_*`` diagnostics.
        """
        cfg = self.config
        scores = np.array([h.score for h in searched.hypotheses])
        peaks = np.argsort(-scores, kind='stable')[: cfg.bev_search.guided_peaks]
        found: list[HypothesisScore] = []
        counts = []
        for peak in peaks:
            corr = guided_correspondences(
                source,
                target,
                searched.hypotheses[peak].T_target_source,
                cfg.bev_search.guided_radius,
                self.compatibility,
            )
            counts.append(len(corr))
            if len(corr) < 3:
                continue
            p, q = source.keypoints[corr.source], target.keypoints[corr.target]
            estimated = estimate(p, q, cfg.estimator)
            verified = self.verify(estimated, p, q, source, target)
            found += [dataclasses.replace(h, origin='guided') for h in verified.hypotheses]
        diagnostics['guided_peaks'] = len(peaks)
        diagnostics['guided_correspondences'] = int(np.sum(counts)) if counts else 0
        if not found:
            return None
        best = max(found, key=lambda h: h.score)
        diagnostics['guided_best_score'] = best.score
        return VerificationResult(found, 0)

    def refinement_holds(
        self,
        refined: np.ndarray,
        coarse: np.ndarray,
        source: PreparedScan,
        target: PreparedScan,
    ) -> bool:
        """
        Tell whether ``refined`` scores about as high as ``coarse`` on the dense scans, or higher.

        About: lower by at most ``verification.min_gain`` (the verification's own notion of
        the same score). A refinement that runs away to another place loses more.
        """
        if not np.all(np.isfinite(refined)):
            return False
        overlap, agreement = self.dense(np.stack([coarse, refined]), source, target)
        scores = combined_score(overlap, agreement, self.config.verification)
        return bool(scores[1] >= scores[0] * (1.0 - self.config.verification.min_gain))
