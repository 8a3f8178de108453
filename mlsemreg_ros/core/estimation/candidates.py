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
The candidate poses of one registration and the rule that chooses among them.

:class:`CandidatePool` holds every verified candidate of a registration (the estimator's
hypotheses, then those of the BEV search and the refused path) with the distinctive
structure each lines up (core/estimation/verification.py, ``distinctive_scores``);
:meth:`CandidatePool.decide` is the choice the confidence rule then judges
(core/estimation/confidence.py, docs/hard_pairs.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.results import HypothesisScore, VerificationResult
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig


@dataclasses.dataclass
class CandidatePool:
    """
    Every verified candidate pose of one registration, with its distinctive structure.

    The estimator's hypotheses (verification) and, once it ran, the BEV search's peaks.
    """

    hypotheses: list[HypothesisScore]
    shares: np.ndarray  # (N,) distinctive share (core/verification.distinctive_scores)
    points: np.ndarray  # (N,) distinctive objects lined up
    views: np.ndarray  # (N,) distinctive objects in the target's view
    incumbent: int = 0  # the verification's choice

    @classmethod
    def of(cls, verified: VerificationResult | None, measure: Any) -> CandidatePool:
        """Pool the verification's candidates (an empty pool without verification)."""
        if verified is None:
            return cls([], np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        pool = cls(
            [],
            np.zeros(0),
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.int64),
            verified.chosen,
        )
        return pool.extended(verified, measure)

    def __bool__(self) -> bool:
        """Tell whether the pool holds a candidate."""
        return bool(self.hypotheses)

    def extended(self, result: VerificationResult, measure: Any) -> CandidatePool:
        """
        Return this pool with ``result``'s hypotheses added.

        ``measure(transforms)`` gives their distinctive ``(shares, objects, in_view)``.
        """
        added = np.stack([h.T_target_source for h in result.hypotheses])
        shares, points, views = measure(added)
        return CandidatePool(
            self.hypotheses + list(result.hypotheses),
            np.concatenate([self.shares, shares]),
            np.concatenate([self.points, points]),
            np.concatenate([self.views, views]),
            self.incumbent,
        )

    def transforms(self) -> np.ndarray:
        """``(N, 4, 4)`` candidate poses."""
        if not self.hypotheses:
            return np.zeros((0, 4, 4))
        return np.stack([h.T_target_source for h in self.hypotheses])

    def scores(self) -> np.ndarray:
        """``(N,)`` verification scores."""
        return np.array([h.score for h in self.hypotheses], dtype=np.float64)

    def origin(self, index: int) -> str:
        """Where candidate ``index`` came from ('estimator' or 'bev_search')."""
        return self.hypotheses[index].origin

    def decide(self, incumbent: int, config: RegistrationConfig, trusted: bool = True) -> int:
        """
        Return the candidate to keep: the best score, then the distinctive structure decides.

        ``incumbent`` is kept unless another scores more than ``verification.min_gain``
        higher. Then, among the candidates scoring at least ``1 - confidence.decide_margin``
        of the winner, those that are *decided* (at least ``confidence.min_distinctive_objects``
        distinctive objects lined up, and ``confidence.min_distinctive_fraction`` of those in
        the target view) replace an undecided winner, and one that lines up more objects
        replaces a decided winner (most objects first, then the best score): at 40 m the
        zero-motion slide overlaps more than the truth, but lines up none of its poles
        (docs/hard_pairs.md). Only while the objects are ``trusted``
        (:func:`~mlsemreg_ros.core.estimation.confidence.objects_trusted`): with flipped
        labels they line up by chance, and the best score decides.
        """
        conf, scores = config.confidence, self.scores()
        best = int(np.argmax(scores))
        winner = (
            best
            if scores[best] > scores[incumbent] * (1.0 + config.verification.min_gain)
            else incumbent
        )
        decided = (
            (self.points >= conf.min_distinctive_objects)
            & (self.points >= conf.min_distinctive_fraction * self.views)
            & trusted
        )
        eligible = decided & (scores >= (1.0 - conf.decide_margin) * scores[winner])
        if eligible.any() and not decided[winner]:
            # the most distinctive objects lined up, then the best score
            key = np.where(eligible, self.points + scores / (scores.max() + 1.0), -np.inf)
            winner = int(np.argmax(key))
        elif eligible.any():
            better = eligible & (self.points > self.points[winner])
            if better.any():
                key = np.where(better, self.points + scores / (scores.max() + 1.0), -np.inf)
                winner = int(np.argmax(key))
        return winner
