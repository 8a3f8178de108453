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
The loop that runs a registration's stages (docs/architecture.md, docs/extending.md).

:class:`~mlsemreg_ros.core.pipeline.Registration` runs its stage list with
:func:`run_stages`; a stage that registers the pair again (the unlabeled rerun of
``core/stages/label_quality.py``) runs the list it was given through it. Both import it
from here, so no stage imports the pipeline.
"""

from __future__ import annotations

from mlsemreg_ros.core.stages.confidence import ConfidenceStage, consider
from mlsemreg_ros.core.stages.context import RegistrationContext, Stage


def run_stages(context: RegistrationContext, stages: list[Stage]) -> RegistrationContext:
    """
    Run ``stages`` in order on ``context`` and return it.

    Each stage that is :meth:`~mlsemreg_ros.core.stages.context.Stage.wanted` (and not
    done by an earlier one) runs, timed as ``<name>_ms``; the candidates a stage returns
    join the pool and face the confidence rule again (``core/stages/confidence.py``).
    """
    for stage in stages:
        if stage.name in context.done or not stage.wanted(context):
            continue
        with context.timed(stage.name):
            found = stage.run(context)
        if found is not None and found.hypotheses:
            with context.timed(ConfidenceStage.name):
                consider(context, found)
    return context
