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


"""The near-miss check (core/alignment/near_miss.py, stage 8): two basins 0.8 m apart."""

from __future__ import annotations

import dataclasses

from mlsemreg_ros.core.alignment.alignment import align_pair, AlignmentCloud
from mlsemreg_ros.core.alignment.near_miss import judge_basins, PointToDistribution
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.pipeline import default_stages
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.fine_alignment import FineAlignmentStage
from mlsemreg_ros.core.stages.near_miss import NearMissStage
import numpy as np
import pytest

#: The true pose of the source scan in the target scan.
T_TRUE = np.array(
    [[1.0, 0.0, 0.0, 0.3], [0.0, 1.0, 0.0, 0.1], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
SPACING = 0.8  # the posts' spacing: the wrong basin is one post along


def fence_scene() -> np.ndarray:
    """
    Ground and two rows of posts 0.8 m apart, with gaps (N, 3).

    Shifted by one post along x, every post meets a post again except at the gaps: a
    second basin 0.8 m from the true one, a little worse.
    """
    grid = np.arange(-12.0, 12.01, 1.0)
    gx, gy = np.meshgrid(grid, grid)
    parts = [np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]]
    angles = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    ring = 0.1 * np.c_[np.cos(angles), np.sin(angles)]
    for y in (4.0, -4.0):
        for k, x in enumerate(np.arange(-8.0, 8.01, SPACING)):
            if k in (5, 6, 13):
                continue
            for z in np.linspace(0.1, 2.0, 12):
                parts.append(np.c_[ring + np.array([x, y]), np.full(len(angles), z)])
    return np.vstack(parts)


def scan(points: np.ndarray) -> PreparedScan:
    """Return a prepared scan with only what the fine alignment and the near-miss check read."""
    return PreparedScan(
        points,
        np.zeros(len(points), np.int32),
        np.zeros((0, 3)),
        np.zeros(0, np.int64),
        np.zeros((0, 8), np.float32),
        np.zeros((0, 1), bool),
        None,
    )


@pytest.fixture(scope='module')
def pair() -> tuple[PreparedScan, PreparedScan]:
    target = fence_scene()
    source = (target - T_TRUE[:3, 3]) @ T_TRUE[:3, :3]
    return scan(source), scan(target)


def shifted(dx: float) -> np.ndarray:
    start = T_TRUE.copy()
    start[0, 3] += dx
    return start


def register_from(pair, start: np.ndarray, config: RegistrationConfig) -> RegistrationContext:
    """Stages 7 and 8 from ``start``, as if the sparse registration had accepted it."""
    source, target = pair
    context = RegistrationContext(source, target, True, config, None)
    context.transform = start
    for stage in (FineAlignmentStage(), NearMissStage()):
        if stage.wanted(context):
            stage.run(context)
    return context


def error(T: np.ndarray) -> tuple[float, float]:
    delta = np.linalg.solve(T_TRUE, T)
    turn = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(delta[:3, 3])), float(turn)


def test_the_scene_has_two_basins_0_8_m_apart(pair):
    """Without the check, a start 0.8 m off converges to the wrong basin and is accepted."""
    config = RegistrationConfig().replace({'near_miss.enabled': False})
    context = register_from(pair, shifted(SPACING), config)
    assert not context.doubts
    shift, _ = error(context.transform)
    assert 0.7 < shift < 0.9  # a near miss: just beyond the 0.6 m bound


@pytest.mark.parametrize('dx', [0.0, 0.1, 0.3, 0.7, SPACING, -SPACING, 0.9, 1.0])
def test_the_accepted_pose_is_the_true_one_or_none(pair, dx):
    context = register_from(pair, shifted(dx), RegistrationConfig())
    shift, turn = error(context.transform)
    if not context.doubts:
        assert shift <= 0.1 and turn <= 0.5, (dx, shift, turn)
    if shift > 0.3:  # landed in the wrong basin: refused, and the diagnostics say why
        assert context.doubts and context.doubts[0].startswith('near miss')
        assert 'two basins' in context.diagnostics['near_miss_refusal']


def test_the_true_basin_is_kept(pair):
    context = register_from(pair, shifted(0.1), RegistrationConfig())
    assert not context.doubts
    assert context.diagnostics['near_miss_refusal'] == ''
    assert error(context.transform)[0] < 0.01


def test_inflate_publishes_a_covariance_that_covers_the_gap(pair):
    config = RegistrationConfig().replace({'near_miss.action': 'inflate'})
    context = register_from(pair, shifted(SPACING), config)
    assert not context.doubts and context.diagnostics['near_miss_inflated']
    sigma_x = np.sqrt(context.alignment.covariance()[0, 0])
    assert sigma_x >= 0.7  # the gap between the basins, along x
    plain = register_from(
        pair, shifted(SPACING), RegistrationConfig().replace({'near_miss.enabled': False})
    )
    assert sigma_x > 10 * np.sqrt(plain.alignment.covariance()[0, 0])


def test_judge_basins_names_the_disputed_direction(pair):
    source, target = (AlignmentCloud.build(s.points, 0.0, 20) for s in pair)
    cfg = RegistrationConfig()
    align = lambda T: align_pair(source, target, T, cfg.fine, 'gicp')  # noqa: E731
    fit = PointToDistribution(source, target, cfg.fine.max_correspondence_distance)
    verdict = judge_basins(align(shifted(-SPACING)), align, fit, cfg.near_miss)
    assert verdict.refusal
    direction = verdict.disputed / np.linalg.norm(verdict.disputed)
    assert abs(direction[0]) > 0.95
    assert 0.7 < np.linalg.norm(verdict.disputed) < 0.9


def test_the_stage_follows_the_fine_alignment_and_has_a_switch(pair):
    names = [stage.name for stage in default_stages()]
    assert names.index('near_miss') == names.index('fine') + 1
    context = RegistrationContext(
        *pair, True, RegistrationConfig().replace({'near_miss.enabled': False}), None
    )
    assert not NearMissStage().wanted(context)


def test_a_strong_sparse_consensus_skips_the_check(pair):
    """More inliers than near_miss.max_inliers: not checked; at or under it, or 0: checked."""

    def wanted(inliers: int, max_inliers: int) -> bool:
        config = RegistrationConfig().replace({'near_miss.max_inliers': max_inliers})
        context = register_from(pair, shifted(1.0), config.replace({'near_miss.enabled': False}))
        context.config = config
        context.doubts.clear()
        context.inliers = np.arange(1000) < inliers
        return NearMissStage().wanted(context)

    assert wanted(200, 200) and wanted(201, 0)
    assert not wanted(201, 200)


def test_better_place_is_a_rival_with_a_lower_residual() -> None:
    from mlsemreg_ros.core.alignment.near_miss import Basin, better_place, NearMiss

    def at(x: float) -> np.ndarray:
        T = np.eye(4)
        T[0, 3] = x
        return T

    cfg = RegistrationConfig().near_miss
    home = Basin(at(0.0), 0.60, 5.0)
    same = Basin(at(0.1), 0.70, 1.0)  # within the agreement: the same place
    deeper = Basin(at(0.8), 0.58, 2.0)  # a rival, lower residual
    deepest_but_poor = Basin(at(-0.8), 0.40, 1.0)  # lower residual, far fewer inliers
    worse = Basin(at(1.6), 0.62, 6.0)
    verdict = NearMiss('near miss', home, [same, deeper, deepest_but_poor, worse])
    assert better_place(verdict, cfg) is deeper
    assert better_place(NearMiss('near miss', home, [worse, same]), cfg) is None


@pytest.mark.parametrize('dx', [SPACING, -SPACING])
def test_downsampled_starts_still_refuse_the_fence_near_miss(pair, dx):
    """``near_miss.pair_downsampled``: starts on the downsampled source find the other basin."""
    config = RegistrationConfig().replace({'near_miss.pair_downsampled': True})
    context = register_from(pair, shifted(dx), config)
    assert context.doubts and 'two basins' in context.diagnostics['near_miss_refusal']
    kept = register_from(pair, shifted(0.1), config)
    assert not kept.doubts and error(kept.transform)[0] < 0.01


def test_home_first_stops_only_a_start_plainly_back_home() -> None:
    """A start near home after ``home_iterations`` stops; any other runs in full, as before."""
    from mlsemreg_ros.core.alignment.alignment import Alignment
    from mlsemreg_ros.core.alignment.near_miss import home_first

    def at(x: float) -> np.ndarray:
        T = np.eye(4)
        T[0, 3] = x
        return T

    calls = []

    def align(start: np.ndarray, iterations: int) -> Alignment:
        """Fake the solver: from +0.6 m home (0.05 m after 4 steps); from -0.6 m on to -0.8 m."""
        calls.append(iterations)
        x = start[0, 3]
        if x > 0:  # heads home
            end, converged = (0.05 if iterations < 20 else 0.0), False
        else:  # passes 0.3 m of home after 4 steps, ends in another basin
            end, converged = (-0.3 if iterations < 20 else -0.8), iterations >= 20
        if x == 2.0:  # converged within the first steps
            end, converged = 1.5, True
        return Alignment(at(end), start, converged, iterations, 10, 10, 1.0, np.eye(6))

    cfg = RegistrationConfig().near_miss  # home: 0.25 x 0.4 m = 0.1 m, 0.25 deg
    home = Alignment(at(0.0), at(0.0), True, 7, 10, 10, 1.0, np.eye(6))
    aligned = home_first(align, home, cfg, 20)
    assert aligned(at(0.6)).T_target_source[0, 3] == 0.05 and calls == [4]
    calls.clear()
    assert aligned(at(-0.6)).T_target_source[0, 3] == -0.8 and calls == [4, 20]
    calls.clear()
    assert aligned(at(2.0)).T_target_source[0, 3] == 1.5 and calls == [4]
    calls.clear()
    off = home_first(align, home, dataclasses.replace(cfg, home_iterations=0), 20)
    assert off(at(0.6)).T_target_source[0, 3] == 0.0 and calls == [20]
    calls.clear()
    unconverged = dataclasses.replace(home, converged=False)  # no minimum: every start runs
    assert home_first(align, unconverged, cfg, 20)(at(0.6)).T_target_source[0, 3] == 0.0
    assert calls == [20]
