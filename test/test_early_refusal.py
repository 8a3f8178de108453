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
The early refusal of the refused path (core/stages/early_refusal.py, issue 30 part 3).

A refused pair whose gate measured a hopeless best covisible overlap in its last trial skips
the full graph, the polishing and the end stages; one above the bound, one whose last trial
was not measured, one whose unlabeled attempt waits, and every pair with the rule off run
them all. Its place in the stage list: after the last gate, before the full graph.
"""

from __future__ import annotations

from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.pipeline import default_stages
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.early_refusal import EarlyRefusalStage
from mlsemreg_ros.core.stages.runner import run_stages

REFUSED = '6 inliers < estimator.min_inliers=40'
SKIPPED = ['full_graph', 'polish', 'covisibility', 'fine']


class Recorder:
    """A stage that records that it ran."""

    def __init__(self, name: str, ran: list[str]) -> None:
        self.name, self.ran = name, ran

    def wanted(self, context: RegistrationContext) -> bool:
        return True

    def run(self, context: RegistrationContext) -> None:
        self.ran.append(self.name)


def refused(overlaps: list[float], bound: float = 0.7, tries: int | None = None):
    """
    Return a refused context whose gate measured ``overlaps``; the rule at ``bound``.

    ``tries``: the gate's trials (default: one per overlap).
    """
    config = RegistrationConfig().replace({'covisibility.early_refuse_overlap': bound})
    context = RegistrationContext(None, None, True, config, None)
    context.refusal, context.searched = REFUSED, SimpleNamespace()
    context.diagnostics.update(
        covisible_early_overlaps=list(overlaps),
        covisible_early_tries=len(overlaps) if tries is None else tries,
    )
    return context


def stages_after(context: RegistrationContext) -> list[str]:
    """Run the rule and then the stages it may skip; return those that ran."""
    ran: list[str] = []
    stages = [EarlyRefusalStage(SKIPPED), *(Recorder(name, ran) for name in SKIPPED)]
    run_stages(context, stages)
    return ran


def test_a_hopeless_pool_is_refused_before_the_full_graph():
    context = refused([0.55, 0.62, 0.66])
    assert stages_after(context) == []
    assert context.refusal == REFUSED
    assert context.diagnostics['covisible_early_refused'] == 0.66


def test_the_last_trial_decides():
    """A first trial below the bound does not refuse: a later search raised the pool."""
    assert stages_after(refused([0.42, 0.74])) == SKIPPED
    assert stages_after(refused([0.74, 0.69])) == []


def test_the_rule_is_off_at_zero_and_without_a_measured_last_trial():
    assert stages_after(refused([0.5], bound=0.0)) == SKIPPED
    assert stages_after(refused([0.5], tries=2)) == SKIPPED  # the last trial measured nothing
    assert stages_after(refused([])) == SKIPPED


def test_never_without_the_fine_alignment_or_with_an_unlabeled_attempt_waiting():
    context = refused([0.5])
    context.refine = False
    assert stages_after(context) == SKIPPED
    context = refused([0.5])
    context.unlabeled_attempt = context
    assert stages_after(context) == SKIPPED
    context = refused([0.5])
    context.refusal = ''
    assert stages_after(context) == SKIPPED


def test_it_sits_after_the_last_gate_and_skips_every_later_stage_but_the_rerun():
    names = [stage.name for stage in default_stages()]
    at = names.index('early_refuse')
    assert names[at - 1] == 'early_accept' and names[at - 2] == 'guided'
    rule = default_stages()[at]
    after = at + 1
    assert rule.skipped == set(names[after:-1])
    assert names[-1] == 'unlabeled_rerun' and 'unlabeled_rerun' not in rule.skipped
    assert RegistrationConfig().covisibility.early_refuse_overlap == 0.70  # on by default
