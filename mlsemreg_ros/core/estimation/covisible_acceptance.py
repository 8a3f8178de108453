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
Acceptance of a refused far pose on its overlap where both scans see (issue 30).

Two scans 60 m apart share a thin lens of space: the right pose holds 0-20 sparse inliers
(``estimator.min_inliers`` is 40) and puts 4-20 % of the source on the target, so the
confidence rule refuses it. After the covisible refinement
(core/stages/covisible_refinement.py) the right poses of the 40 and 60 m dev pairs measure a
covisible overlap (core/estimation/covisibility.py) of 0.98-1.00, and every other candidate
of their pool and every slide of them stays at least 0.05 below. The rule here accepts a
refused pose on that evidence when

- its tilt is within ``covisibility.accept_tilt`` (and the level check passes, in the stage);
- measured on ``covisibility.accept_points`` points of each scan (the covisible choice's
  2000 leave a few dozen checked points at 60 m, too few for a margin of 0.03), its own
  covisible overlap reaches ``covisibility.accept_overlap`` with at least
  ``covisibility.accept_checked`` of its surface checkable;
- the ``covisibility.accept_rivals`` best *distinct* candidates of the pool (farther than
  ``confidence.rival_translation`` / ``confidence.rival_rotation``) and the pose slid by
  ``confidence.slide_distance`` along eight horizontal directions, measured the same way,
  stay ``covisibility.accept_gap`` below it: nothing else the search found, and no slide
  along a straight street, fits the free space as well.

Measured figures and the sets it was calibrated on: docs/long_range.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

from mlsemreg_ros.core.poses import same_pose
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.estimation.covisibility import CovisibilityConfig


@dataclass(frozen=True)
class CovisibleEvidence:
    """The covisible overlap of a refined refused pose against its rivals'."""

    overlap: float  # mutual covisible overlap of the pose (on / (on + seen through))
    checked: float  # the smaller checkable share of the two scans' surfaces
    rival_overlap: float  # best of the distinct pool candidates with enough checked (0: none)
    rival_checked: float  # its checked share
    slide_overlap: float  # best of the pose slid along 8 directions (0: no slides)
    slide_checked: float  # its checked share
    tilt_deg: float  # angle between the scans' up axes under the pose
    near_overlap: float = 0.0  # best of the pose slid by a metre or so (0: not measured)

    def as_diagnostics(self) -> dict[str, float]:
        """Flat values for the result's diagnostics (``covisible_accept_*``)."""
        return {f'covisible_accept_{k}': float(v) for k, v in asdict(self).items()}


def best_eligible(
    overlap: np.ndarray, checked: np.ndarray, min_checked: float
) -> tuple[float, float]:
    """``(overlap, checked)`` of the best pose with ``checked >= min_checked`` ((0, 0): none)."""
    eligible = checked >= min_checked
    if not eligible.any():
        return 0.0, 0.0
    best = int(np.argmax(np.where(eligible, overlap, -np.inf)))
    return float(overlap[best]), float(checked[best])


def acceptance_refusal(evidence: CovisibleEvidence, covis: CovisibilityConfig) -> str:
    """Why the covisible evidence does not accept the pose ('' when it does; module docstring)."""
    if covis.accept_overlap <= 0.0:
        return 'covisibility.accept_overlap=0 (off)'
    reasons = []
    if evidence.overlap < covis.accept_overlap:
        reasons.append(
            f'covisible overlap {evidence.overlap:.3f} < covisibility.accept_overlap='
            f'{covis.accept_overlap:g}'
        )
    if evidence.checked < covis.accept_checked:
        reasons.append(
            f'{evidence.checked:.3f} of the surface checked < covisibility.accept_checked='
            f'{covis.accept_checked:g}'
        )
    ceiling = evidence.overlap - covis.accept_gap
    for what, value in (
        ('a distinct candidate', evidence.rival_overlap),
        ('a slide', evidence.slide_overlap),
    ):
        if value > ceiling:
            reasons.append(
                f'{what} reaches a covisible overlap {value:.3f} > {evidence.overlap:.3f} - '
                f'covisibility.accept_gap={covis.accept_gap:g}'
            )
    climb = (evidence.near_overlap - evidence.overlap) * evidence.checked
    if climb > covis.accept_climb:
        reasons.append(
            f'a slide of {covis.accept_near_slide:g}-{1.5 * covis.accept_near_slide:g} m fits '
            f'{climb:.4f} more of the surface ({evidence.near_overlap:.3f} against '
            f'{evidence.overlap:.3f} on {evidence.checked:.2f} checked) > '
            f'covisibility.accept_climb={covis.accept_climb:g}: the pose is not where the '
            'scans fit best'
        )
    return '; '.join(reasons)


def tilt_refusal(tilt_deg: float, covis: CovisibilityConfig) -> str:
    """Why the tilt forbids an acceptance on the covisible overlap ('' when it does not)."""
    if tilt_deg <= covis.accept_tilt:  # NaN fails
        return ''
    return f'tilt {tilt_deg:.1f} deg > covisibility.accept_tilt={covis.accept_tilt:g}'


def localizability_refusal(ratio: float | None, covis: CovisibilityConfig) -> str:
    """
    Why the refined pose is too weakly constrained for the covisible evidence ('' if it is not).

    ``ratio``: the fine alignment's ``degeneracy_ratio`` (smallest over largest eigenvalue of
    the translation Hessian; None: not measured, nothing to refuse on). The covisible overlap
    counts a point as seen through only a metre (``covisibility.margin``) in front of the
    other scan, so a pose slid along a street's weak direction by a metre still measures 1.0.
    """
    if covis.accept_localizability <= 0.0 or ratio is None:
        return ''
    if ratio >= covis.accept_localizability:  # NaN refuses
        return ''
    return (
        f"the refined pose's localizability {ratio:.3g} (degeneracy_ratio) < "
        f'covisibility.accept_localizability={covis.accept_localizability:g}'
    )


def best_rivals(
    pose: np.ndarray,
    transforms: np.ndarray,
    overlap: np.ndarray,
    checked: np.ndarray,
    min_checked: float,
    rotation_deg: float,
    translation_m: float,
    count: int,
) -> np.ndarray:
    """
    Return the ``count`` candidates distinct from ``pose`` with the best overlap (indices).

    Candidates ``transforms`` ``(N, 4, 4)`` with their covisible ``overlap`` and
    ``checked`` ``(N,)``; only those with ``checked >= min_checked`` count.
    """
    if len(transforms) == 0:
        return np.zeros(0, dtype=np.int64)
    distinct = ~same_pose(pose, transforms, rotation_deg, translation_m)
    eligible = np.flatnonzero(distinct & (checked >= min_checked))
    return eligible[np.argsort(-overlap[eligible], kind='stable')[:count]]
