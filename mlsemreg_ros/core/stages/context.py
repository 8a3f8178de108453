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
The shared, typed state of one registration, and the interface of a stage.

``Registration.register`` (core/pipeline.py) makes one :class:`RegistrationContext` per
pair and runs each :class:`Stage` whose :meth:`Stage.wanted` says yes:

- the loop times the stage (``timings_ms[stage.name + '_ms']``);
- candidates a stage returns join the pool and face the confidence rule again
  (``core/stages/confidence.py``, timed as ``confidence_ms``);
- the verdict comes from the context: the confidence rule's refusal first, then the
  doubts of later stages (:meth:`RegistrationContext.doubt`), and the message says the
  first of them before what the matching and the search said.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
import time
from typing import Any, Protocol, TYPE_CHECKING

from mlsemreg_ros.core.results import (
    Correspondences,
    EstimateResult,
    PreparedScan,
    RegistrationResult,
    VerificationResult,
)
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.alignment.alignment import Alignment
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.estimation.candidates import CandidatePool
    from mlsemreg_ros.core.estimation.confidence import Evidence
    from mlsemreg_ros.core.features.levelling import GroundFit
    from mlsemreg_ros.core.labeling.quality import LabelQuality
    from mlsemreg_ros.core.stages.scoring import Scoring


@contextmanager
def timed(timings: dict[str, float], stage: str) -> Iterator[None]:
    """Add the wall time of the ``with`` block to ``timings[stage]`` (milliseconds)."""
    start = time.perf_counter()
    yield
    timings[stage] = timings.get(stage, 0.0) + 1e3 * (time.perf_counter() - start)


@dataclass
class RegistrationContext:
    """
    Everything the stages of one registration share; each field names the stage that sets it.

    ``transform`` is always the current ``T_target_source`` (``p_target = T @ p_source``).
    """

    source: PreparedScan
    target: PreparedScan
    refine: bool  # the pair's fine alignment runs (False: the odometry refines on its map)
    config: RegistrationConfig
    scoring: Scoring  # the verification's scores with this config (core/stages/scoring.py)
    timings_ms: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    label_names: tuple[str, ...] = ()  # the label map's class names, by learning id
    # levelling (core/stages/levelling.py): the two scans' ground fits, once measured
    ground_fits: tuple[GroundFit | None, GroundFit | None] | None = None
    # label quality
    label_quality: LabelQuality | None = None  # the pair's labels judged (None: not judged)
    #: poorer labels: the unlabeled attempt, accepted but not strong enough to be taken
    #: first; the labelled path falls back to it when it refuses (core/stages/label_quality.py)
    unlabeled_attempt: RegistrationContext | None = None
    # matching
    correspondences: Correspondences | None = None
    source_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (K, 3)
    target_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (K, 3)
    mode: str = ''  # 'ml-semreg', 'gm-only' or 'plain'
    message: str = ''  # why the matching fell back
    # estimation, verification
    estimated: EstimateResult | None = None
    transform: np.ndarray = field(default_factory=lambda: np.full((4, 4), np.nan))
    verified: VerificationResult | None = None
    # confidence
    pool: CandidatePool | None = None
    chosen: int | None = None  # index into pool.hypotheses (None: the estimator's pose)
    trusted: bool = True  # the distinctive objects may decide (confidence.objects_trusted)
    #: the labels', the distinctive classes' and the information ceiling (label_model.py)
    ceilings: tuple[float, float, float] = (1.0, 1.0, float('nan'))
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (K,)
    evidence: Evidence | None = None
    refusal: str = ''  # the confidence rule's verdict on ``transform`` ('' = accepted)
    # BEV search and the refused path
    searched: VerificationResult | None = None  # the BEV search's candidates
    search_reason: str = ''  # why the search ran ('' = it did not)
    #: the scans' covisible sides by sample count and scan (``covisible_sides``), made once
    covisible_sides: dict[tuple[int, int, int], tuple[Any, Any]] = field(default_factory=dict)
    #: the covisible (overlap, checked) of the pool's first candidates, and those candidates
    covisible_measured: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    # the gate (early_acceptance.py): the poses its trials took to the fine alignment
    early_tried: list[np.ndarray] = field(default_factory=list)
    # covisibility: the pool's covisible (overlap, checked), once the covisible choice ran
    covisible_pool: tuple[np.ndarray, np.ndarray] | None = None
    # fine alignment
    coarse: np.ndarray | None = None  # the pose before the fine alignment
    alignment: Alignment | None = None
    doubts: list[str] = field(default_factory=list)  # later stages' reasons to refuse
    done: set[str] = field(default_factory=set)  # stages an earlier stage did (label quality)

    def timed(self, stage: str) -> Any:
        """Time a ``with`` block as ``timings_ms[stage + '_ms']``."""
        return timed(self.timings_ms, f'{stage}_ms')

    def doubt(self, reason: str) -> None:
        """Refuse the pose for ``reason`` (an accepted pose takes the first reason given)."""
        if reason:
            self.doubts.append(reason)

    def result(self) -> RegistrationResult:
        """Return the registration's result: the transform, the verdict and what led to it."""
        diagnostics, message = self.diagnostics, self.message
        if self.search_reason:  # the search ran: say which stage's pose won
            origin = self.pool.origin(self.chosen)
            diagnostics['bev_search_used'] = origin == 'bev_search'
            diagnostics['chosen_origin'] = origin
            if origin != 'estimator':
                message = f"{origin} pose (the estimator's was {self.search_reason})"
        diagnostics.update(self.evidence.as_diagnostics())
        reasons = [self.refusal] if self.refusal else self.doubts[:1]
        return RegistrationResult(
            self.transform,
            self.correspondences,
            self.source_points,
            self.target_points,
            self.inliers,
            not reasons,
            self.mode,
            '; '.join([*reasons, message] if message else reasons),
            self.timings_ms,
            diagnostics,
            self.transform if self.coarse is None else self.coarse,
            self.alignment,
        )


class Stage(Protocol):
    """
    One job of a registration (core/stages/): reads and writes the context.

    ``name`` times it (``<name>_ms``). ``run`` may return verified candidates: they join
    the pool and face the confidence rule (a candidate source such as the BEV search).
    """

    name: str

    def wanted(self, context: RegistrationContext) -> bool:
        """Tell whether the stage runs for this pair (its switch and its trigger)."""

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Do the stage's job on ``context``; new candidates or None."""
