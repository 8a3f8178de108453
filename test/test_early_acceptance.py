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
The gate of the refused path (core/stages/early_acceptance.py, issue 30 part 5).

The end stages are stand-ins that record their calls and set what the real ones set, so
each rule of the gate is checked on its own: a pose stage 9 accepts beyond doubt ends the
search, one it accepts by less than ``covisibility.early_accept_gap`` does not, a distinct
candidate within the gap stops the trial before the fine alignment, a pose is tried once (each
trial's covisible choice is kept in the diagnostics).
The pool's covisible overlaps measured in parts equal one measurement of the whole pool.
"""

from __future__ import annotations

from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation.covisibility import mutual_covisible_overlap
from mlsemreg_ros.core.pipeline import default_stages, Registration
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.covisibility import covisible_side, pool_covisible_overlap
from mlsemreg_ros.core.stages.early_acceptance import EarlyAcceptanceStage
import numpy as np
import pytest
from test_covisible_acceptance import facade_street
from test_long_range import pose, scan

REFUSED = '6 inliers < estimator.min_inliers=40'
LATER = ['bev_search_swapped', 'far_search', 'guided', 'full_graph', 'polish']


class Covisible:
    """Stand-in of the covisible choice: chooses candidate 0 with the given overlaps."""

    name = 'covisibility'

    def __init__(self, overlap: np.ndarray) -> None:
        self.overlap = np.asarray(overlap, dtype=np.float64)
        self.calls = 0

    def wanted(self, context: RegistrationContext) -> bool:
        return bool(context.refusal)

    def run(self, context: RegistrationContext) -> None:
        self.calls += 1
        checked = np.full(len(self.overlap), 0.1)
        context.covisible_pool = context.covisible_measured = (self.overlap, checked)
        context.chosen = 0
        context.transform = context.pool.transforms()[0]
        context.diagnostics['covisible_overlap'] = float(self.overlap[0])


class Accept:
    """Stand-in of the fine alignment and stage 9: accepts with the given rival overlap."""

    name = 'covisible_accept'

    def __init__(self, overlap: float, rival: float) -> None:
        self.overlap, self.rival, self.calls = overlap, rival, 0

    def wanted(self, context: RegistrationContext) -> bool:
        return bool(context.refusal)

    def run(self, context: RegistrationContext) -> None:
        self.calls += 1
        context.diagnostics.update(
            covisible_accepted=True,
            covisible_accept_overlap=self.overlap,
            covisible_accept_rival_overlap=self.rival,
            covisible_accept_slide_overlap=0.5,
        )
        context.refusal = ''


def refused(candidates: np.ndarray, gap: float = 0.08) -> RegistrationContext:
    """Return a refused context after a BEV search: pool ``candidates``, the gate at ``gap``."""
    config = RegistrationConfig().replace({'covisibility.early_accept_gap': gap})
    context = RegistrationContext(None, None, True, config, None)
    context.refusal, context.searched = REFUSED, SimpleNamespace()
    context.pool = _Pool(candidates)
    context.transform = candidates[-1]
    return context


class _Pool:
    def __init__(self, candidates: np.ndarray) -> None:
        self.candidates = candidates

    def __bool__(self) -> bool:
        return len(self.candidates) > 0

    def transforms(self) -> np.ndarray:
        return self.candidates


def candidates() -> np.ndarray:
    """Return the chosen pose, a variant 0.3 m away and a distinct pose 20 m away."""
    return np.stack([np.eye(4), pose(0.3, 0.0, 0.0, 0.0), pose(20.0, 0.0, 0.0, 0.0)])


def test_the_gate_sits_after_each_search_but_the_last_and_is_on_by_default():
    names = [stage.name for stage in default_stages()]
    gates = [i for i, name in enumerate(names) if name == 'early_accept']
    assert [names[i - 1] for i in gates] == [
        'bev_search',
        'bev_search_swapped',
        'far_search',
        'guided',
    ]
    context = refused(candidates(), gap=0.0)
    assert not EarlyAcceptanceStage([], LATER).wanted(context)
    assert RegistrationConfig().covisibility.early_accept_gap == 0.08  # 2 x accept_gap


def test_the_gate_never_runs_without_the_pair_s_fine_alignment():
    """The odometry registers with refine=False: stage 9 never runs, so neither does the gate."""
    context = refused(candidates())
    context.refine = False
    assert not EarlyAcceptanceStage([], LATER).wanted(context)


def test_a_pose_accepted_beyond_doubt_ends_the_search():
    context = refused(candidates())
    covisible, accept = Covisible([0.99, 0.99, 0.80]), Accept(0.99, 0.85)
    stage = EarlyAcceptanceStage([covisible, accept], LATER)
    assert stage.wanted(context)
    stage.run(context)
    assert context.refusal == '' and context.diagnostics['covisible_early_accepted']
    assert np.array_equal(context.transform, np.eye(4))
    assert set(LATER) | {'early_accept', 'covisibility', 'covisible_accept'} <= context.done
    assert context.diagnostics['covisible_early_gap'] == pytest.approx(0.14)


def test_a_pose_accepted_by_less_than_the_gap_leaves_the_search_going():
    """Stage 9 accepts (gap 0.05 > accept_gap 0.04) but not beyond the gate's 0.08."""
    context = refused(candidates())
    stage = EarlyAcceptanceStage([Covisible([0.99, 0.99, 0.80]), Accept(0.99, 0.94)], LATER)
    stage.run(context)
    assert context.refusal == REFUSED and not context.done
    assert 'covisible_early_accepted' not in context.diagnostics
    assert np.array_equal(context.transform, candidates()[-1])  # the copy was dropped


def test_a_pose_accepted_without_stage_9_s_measure_is_not_taken():
    """Accepted by the confidence rule, but not refined (no alignment to measure): dropped."""

    class Confident(Covisible):
        def run(self, context: RegistrationContext) -> None:
            super().run(context)
            context.refusal = ''  # the covisible overlap stands in for the overlap

    context = refused(candidates())
    EarlyAcceptanceStage([Confident([0.99, 0.99, 0.80])], LATER).run(context)
    assert context.refusal == REFUSED and not context.done
    assert np.isnan(context.diagnostics['covisible_early_gap'])


def test_a_distinct_candidate_within_the_gap_stops_the_trial_before_the_fine_alignment():
    """The variant 0.3 m away does not count; the pose 20 m away at 0.95 does."""
    context = refused(candidates())
    accept = Accept(0.99, 0.5)
    EarlyAcceptanceStage([Covisible([0.99, 0.99, 0.95]), accept], LATER).run(context)
    assert accept.calls == 0 and context.refusal == REFUSED
    # the pool's measurement is kept for the covisible choice at the end
    assert context.covisible_measured is not None


def test_a_pose_is_taken_to_stage_9_once():
    context = refused(candidates())
    accept = Accept(0.99, 0.94)  # not beyond doubt
    stage = EarlyAcceptanceStage([Covisible([0.99, 0.99, 0.80]), accept], LATER)
    stage.run(context)
    stage.run(context)
    assert accept.calls == 1 and context.diagnostics['covisible_early_tries'] == 2
    # each trial's covisible choice, for the study of an early refusal (docs/hard_pairs.md)
    assert context.diagnostics['covisible_early_overlaps'] == [0.99, 0.99]


def test_the_pool_measured_in_parts_equals_one_measurement():
    """The gate's trials measure the pool so far; the end measures only what was added."""
    world, labels = facade_street()
    registration = Registration(RegistrationConfig())
    T_ws, T_wt = pose(0.0, 0.0, 1.7, 0.0), pose(60.0, -1.0, 1.7, 175.0)
    source = registration.prepare(*scan(world, labels, T_ws))
    target = registration.prepare(*scan(world, labels, T_wt))
    truth = np.linalg.inv(T_wt) @ T_ws
    poses = np.stack([truth @ pose(dx, 0.0, 0.0, yaw) for dx, yaw in [(0, 0), (6, 0), (0, 30)]])
    poses = np.concatenate([poses, poses[:2] @ pose(0.0, 2.0, 0.0, 3.0)])
    context = RegistrationContext(source, target, True, registration.config, None)
    first = pool_covisible_overlap(context, poses[:3])
    whole = pool_covisible_overlap(context, poses)
    cfg = registration.config
    sides = [
        covisible_side(s, cfg.covisibility.bin_deg, cfg.verification) for s in (source, target)
    ]
    expected = mutual_covisible_overlap(
        poses, *sides, cfg.verification.overlap_distance, cfg.covisibility.margin
    )
    # the same figures, but for the rounding of the weighted sums' blocks (BLAS)
    np.testing.assert_allclose(whole, expected, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(first, np.asarray(expected)[:, :3], rtol=0.0, atol=1e-12)
    assert whole[0][0] > 0.97 > whole[0][1]  # the truth and its 6 m slide, told apart
