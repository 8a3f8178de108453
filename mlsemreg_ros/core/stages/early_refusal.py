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
The early refusal of the refused path: no search after the guided re-matching, hopeless.

After the guided re-matching (stage 6) the pool holds every candidate of the BEV, swapped
and far searches, and the gate (``core/stages/early_acceptance.py``) has measured the best
covisible overlap among them in each of its trials (``covisible_early_overlaps``). What
follows, the full graph, the polishing and the end stages (the covisible choice, the fine
alignment, stage 9), only refines those candidates. On the dev pairs 40 and 60 m apart and
the simulated far pairs (docs/hard_pairs.md, "The early refusal"), no pose that ended right,
accepted or not, had a best covisible overlap below 0.738 in the last trial, and none
accepted below 0.878. A pair still refused whose last trial measured less than
``covisibility.early_refuse_overlap`` is therefore refused here: the later searches and the
end stages are skipped and the current (refused) pose is returned unrefined. ``0``: off.

Only with the pair's fine alignment (``refine``, where the gate runs), never when the poorer
labels' unlabeled attempt waits to be taken (the unlabeled fallback must still run), and
only when every trial of the gate measured its covisible choice (so the last figure is the
last trial's).
"""

from __future__ import annotations

from collections.abc import Sequence

from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext


class EarlyRefusalStage:
    """Refuse a pose whose best covisible overlap after the searches is hopeless."""

    name = 'early_refuse'

    def __init__(self, skipped: Sequence[str]) -> None:
        """``skipped``: the stages a refusal here makes done (later searches, end stages)."""
        self.skipped = frozenset(skipped)

    def wanted(self, context: RegistrationContext) -> bool:
        """``covisibility.early_refuse_overlap`` > 0, ``refine``, searched, still refused."""
        found = context.diagnostics
        overlaps = found.get('covisible_early_overlaps', [])
        return (
            context.config.covisibility.early_refuse_overlap > 0.0
            and context.refine
            and context.searched is not None
            and bool(context.refusal)
            and context.unlabeled_attempt is None
            and len(overlaps) > 0
            and len(overlaps) == found.get('covisible_early_tries', 0)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Refuse here when the last trial's best covisible overlap is below the bound."""
        last = context.diagnostics['covisible_early_overlaps'][-1]
        if last < context.config.covisibility.early_refuse_overlap:  # NaN: not refused here
            context.diagnostics['covisible_early_refused'] = last
            context.done.update(self.skipped)
        return None
