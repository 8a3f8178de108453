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
The near-miss check: an accepted, refined pose must sit in the one basin of its pair.

A fine alignment converges to the nearest local minimum of its cost. When a sparse global
registration lands a metre off, GICP may settle in a neighbouring basin (on KITTI pairs
40 m apart: 0.79 m / 1.95 deg off the truth, just past the 0.6 m / 5 deg bounds), and
the confidence rule, which judged the sparse pose, cannot see it. So the refined pose is
aligned again from perturbed starts (:func:`perturbed_starts`: along the weakest
horizontal direction of the alignment's Hessian, both ways, with a small yaw):

- every start that converges back within ``near_miss.agreement_*`` agrees;
- a start that converges elsewhere found another basin; it **disputes** the pose when it
  is about as good: an inlier share at least ``near_miss.rival_share`` times the refined
  pose's, and a point-to-distribution residual (:class:`PointToDistribution`) at most
  ``1 / rival_share`` times it. A clearly worse basin is what a start falling off the
  true minimum finds, and leaves the pose standing.

:func:`judge_basins` returns the verdict; the pair stage (core/stages/near_miss.py)
refuses a disputed pose or inflates its covariance along the disputed direction
(:func:`disputed_hessian`) so its standard deviation there covers the gap.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from mlsemreg_ros.core.alignment.alignment import Alignment, AlignmentCloud
from mlsemreg_ros.core.alignment.config import NearMissConfig
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np


@dataclass(frozen=True)
class Basin:
    """Where one alignment converged and how well it fits there."""

    T_target_source: np.ndarray  # (4, 4)
    inlier_fraction: float
    residual: float  # mean point-to-distribution residual of the inliers (inf: none)
    alignment: Alignment | None = None  # the alignment that converged there


@dataclass(frozen=True)
class NearMiss:
    """The near-miss verdict of one refined pose."""

    refusal: str  # '' when the pose stands
    refined: Basin
    others: list[Basin] = field(default_factory=list)  # each perturbed start's basin
    disputed: np.ndarray | None = None  # (3,) translation to the rival basin, target frame

    def as_diagnostics(self) -> dict[str, float | int | str]:
        """``near_miss_*`` diagnostics: the refined fit, the spread, the verdict."""
        gaps = [_gap(self.refined.T_target_source, b.T_target_source) for b in self.others]
        return {
            'near_miss_inlier_fraction': self.refined.inlier_fraction,
            'near_miss_residual': self.refined.residual,
            'near_miss_max_gap_m': max((g[0] for g in gaps), default=0.0),
            'near_miss_max_gap_deg': max((g[1] for g in gaps), default=0.0),
            'near_miss_other_shares': ' '.join(f'{b.inlier_fraction:.3f}' for b in self.others),
            'near_miss_refusal': self.refusal,
        }


class PointToDistribution:
    """The point-to-distribution (NDT-style) fit of a source cloud on a target's Gaussians."""

    def __init__(
        self,
        source: AlignmentCloud,
        target: AlignmentCloud,
        max_distance: float,
        regularization: float = 1e-3,
    ) -> None:
        """
        Keep the clouds; the target's covariances (small_gicp's) get ``regularization`` m^2.

        A source point is an inlier when its nearest target point is within
        ``max_distance``.
        """
        self.source, self.target, self.max_distance = source.points, target, max_distance
        covs = np.asarray(target.cloud.covs(), dtype=np.float64).reshape(-1, 4, 4)
        self.covs = covs[:, :3, :3] + regularization * np.eye(3)

    def __call__(self, alignment: Alignment) -> tuple[float, float]:
        """
        Return (inlier share, mean residual) where ``alignment`` converged.

        The residual of a point is its squared Mahalanobis distance to its nearest target
        point under that point's covariance; the mean is over the inliers (inf: none).
        """
        if not len(self.source) or not len(self.target):
            return 0.0, float('inf')
        T_target_source = alignment.T_target_source
        moved = self.source @ T_target_source[:3, :3].T + T_target_source[:3, 3]
        index, squared = self.target.tree.batch_nearest_neighbor_search(moved, 1)
        index, squared = np.asarray(index).ravel(), np.asarray(squared).ravel()
        inlier = (index >= 0) & (squared <= self.max_distance**2)
        if not inlier.any():
            return 0.0, float('inf')
        residual = moved[inlier] - self.target.points[index[inlier]]
        whitened = np.linalg.solve(self.covs[index[inlier]], residual[..., None])[..., 0]
        return float(inlier.mean()), float(np.einsum('ni,ni->n', residual, whitened).mean())


def perturbed_starts(alignment: Alignment, cfg: NearMissConfig) -> list[np.ndarray]:
    """
    Return the perturbed starts around the refined pose ``alignment.T_target_source``.

    The shift is ``near_miss.offset`` along the weakest horizontal translation direction of
    the Hessian (source frame), both ways, with ``±near_miss.yaw_offset``; with 4 starts,
    also along the perpendicular. A Hessian that says nothing gives the source x axis.
    """
    H = np.asarray(alignment.hessian, dtype=np.float64)
    weak = np.array([1.0, 0.0])
    if H.shape == (6, 6) and np.all(np.isfinite(H)) and np.any(H[3:5, 3:5]):
        weak = np.linalg.eigh(0.5 * (H[3:5, 3:5] + H[3:5, 3:5].T))[1][:, 0]
    directions = [weak, np.array([-weak[1], weak[0]])][: cfg.starts // 2]
    yaw = np.radians(cfg.yaw_offset)
    starts = []
    for direction in directions:
        for sign in (1.0, -1.0):
            step = np.eye(4)
            c, s = np.cos(sign * yaw), np.sin(sign * yaw)
            step[:2, :2] = [[c, -s], [s, c]]
            step[:2, 3] = sign * cfg.offset * direction
            starts.append(alignment.T_target_source @ step)
    return starts


def home_first(
    align: Callable[[np.ndarray, int], Alignment],
    refined: Alignment,
    cfg: NearMissConfig,
    max_iterations: int,
) -> Callable[[np.ndarray], Alignment]:
    """
    Return ``align`` from a start, stopped early where the start is plainly back home.

    ``align(T_initial, iterations)`` is the fine alignment with at most ``iterations``
    Gauss-Newton iterations. Each start first runs ``near_miss.home_iterations`` of them:
    a start then within ``near_miss.home_share`` of the agreement bounds of the refined
    pose agrees, whatever its last iterations would add, since the refined pose is the
    converged minimum of the same cost; a start that converged already is final. Any other
    start is aligned again from its start with ``max_iterations``, exactly as without this,
    and so is every start when ``refined`` did not converge (its pose is no minimum: a start
    near it may still drift away; a 60 m probe landing 6 m off showed it).
    """
    home = refined.T_target_source
    early = cfg.home_iterations if refined.converged else 0
    near_shift = cfg.home_share * cfg.agreement_translation
    near_turn = cfg.home_share * cfg.agreement_rotation

    def aligned(start: np.ndarray) -> Alignment:
        if 0 < early < max_iterations:
            first = align(start, early)
            moved = first.T_target_source
            if first.converged:
                return first  # what the full alignment gives
            if np.all(np.isfinite(moved)):
                shift, turn = _gap(home, moved)
                if shift <= near_shift and turn <= near_turn:
                    return first
        return align(start, max_iterations)

    return aligned


def judge_basins(
    refined: Alignment,
    align: Callable[[np.ndarray], Alignment],
    fit: Callable[[Alignment], tuple[float, float]],
    cfg: NearMissConfig,
) -> NearMiss:
    """
    Align again from :func:`perturbed_starts` and say whether another basin disputes ``refined``.

    ``align(T_initial)`` is the same fine alignment as the refined pose's; ``fit(alignment)``
    returns (inlier share, residual) where an alignment converged (pairs: the
    point-to-distribution fit; the odometry: :func:`alignment_fit`).
    """
    home = Basin(refined.T_target_source, *fit(refined), refined)
    if cfg.max_residual > 0 and home.residual > cfg.max_residual:
        return NearMiss(
            f'near miss: point-to-distribution residual {home.residual:.3g} > '
            f'near_miss.max_residual={cfg.max_residual:g}',
            home,
        )
    others, refusal, disputed = [], '', None
    for start in perturbed_starts(refined, cfg):
        again = align(start)
        moved = again.T_target_source
        if not np.all(np.isfinite(moved)):
            continue
        other = Basin(moved, *fit(again), again)
        others.append(other)
        shift, turn = _gap(home.T_target_source, moved)
        if shift <= cfg.agreement_translation and turn <= cfg.agreement_rotation:
            continue
        rival = other.inlier_fraction >= cfg.rival_share * home.inlier_fraction and (
            other.residual * cfg.rival_share <= home.residual
        )
        if rival and not refusal:
            disputed = moved[:3, 3] - home.T_target_source[:3, 3]
            refusal = (
                f'near miss: a start {cfg.offset:g} m off converged {shift:.2f} m / '
                f'{turn:.2f} deg away with inlier share {other.inlier_fraction:.3f} '
                f'(refined {home.inlier_fraction:.3f}) and residual {other.residual:.3g} '
                f'(refined {home.residual:.3g}): two basins'
            )
    return NearMiss(refusal, home, others, disputed)


def better_place(verdict: NearMiss, cfg: NearMissConfig) -> Basin | None:
    """
    Return the rival place with a lower residual than the refined pose, or None.

    A rival (an inlier share at least ``near_miss.rival_share`` times the refined pose's)
    with a lower residual is the same cost's deeper minimum, which the refinement stopped
    short of (the lowest residual of them).
    """
    home = verdict.refined
    better = [
        b
        for b in verdict.others
        if b.inlier_fraction >= cfg.rival_share * home.inlier_fraction
        and b.residual < home.residual
        and _gap(home.T_target_source, b.T_target_source)[0] > cfg.agreement_translation
    ]
    return min(better, key=lambda b: b.residual) if better else None


def alignment_fit(alignment: Alignment) -> tuple[float, float]:
    """Return the alignment's own (inlier share, GICP cost per inlier): the map's fit."""
    if alignment.num_inliers <= 0:
        return 0.0, float('inf')
    return alignment.inlier_fraction, 2.0 * alignment.error / alignment.num_inliers


def disputed_hessian(alignment: Alignment, disputed: np.ndarray) -> np.ndarray:
    """
    Return ``alignment``'s Hessian softened along ``disputed`` (target frame) to cover the gap.

    The translation block is scaled by ``S = I + (1/sqrt(f) - 1) u u^T`` on both sides
    (``u`` the disputed direction in the source frame), so the variance along ``u`` grows
    by ``f`` and the others stay: ``f`` makes the standard deviation along ``u`` (from
    :meth:`Alignment.covariance`) at least the gap between the basins.
    """
    gap = float(np.linalg.norm(disputed))
    H = np.array(alignment.hessian, dtype=np.float64)
    if gap <= 0 or not np.all(np.isfinite(H)):
        return H
    u = alignment.T_target_source[:3, :3].T @ (disputed / gap)
    covariance = alignment.covariance(axes='source')[:3, :3]
    sigma2 = float(u @ covariance @ u)
    factor = max(gap**2 / sigma2, 1.0) if sigma2 > 0 else 1.0
    S = np.eye(6)
    S[3:, 3:] += (1.0 / np.sqrt(factor) - 1.0) * np.outer(u, u)
    return S @ H @ S


def _gap(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Return the translation (m) and rotation (deg) between two poses."""
    delta = np.linalg.solve(T_a, T_b)
    return float(np.linalg.norm(delta[:3, 3])), rotation_angle_deg(delta)
