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
``mlsemreg confidence``: the evidence of right and wrong registrations, and the thresholds.

The study is :mod:`mlsemreg_ros.evaluation.confidence`; this module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError, ConfigOption, SetOption, settings
import typer

HELP = (
    'Register pairs of known outcome (dev pairs both ways, far chain pairs, mirrored '
    'clouds, corrupted labels, simulated drives) with every threshold off, plot their '
    'evidence and count what the configured thresholds accept; run the failure cases '
    'through the odometry.'
)


def confidence(
    dev: Annotated[
        Path | None,
        typer.Option(
            file_okay=False,
            help='folder of the dev pair files (default: ../shared/data/'
            'kitti_pairs_dev or MLSEMREG_DEV_PAIRS)',
        ),
    ] = None,
    bags: Annotated[
        list[Path] | None,
        typer.Option(
            '--bags',
            exists=True,
            help='simulated bags with ground truth (pairs at strides 1, 10, 20; repeatable)',
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help='results folder')] = Path('results/confidence'),
    config: ConfigOption = None,
    overrides: SetOption = None,
) -> int:
    """Measure the confidence evidence (alias mlsemreg-confidence)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.datasets.pairs import dev_pairs_dir
    from mlsemreg_ros.evaluation.confidence import run_study
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.evaluation.tables import print_text

    core, evaluation = settings((RegistrationConfig, EvaluationSettings), config, overrides)
    try:
        lines = run_study(
            dev if dev is not None else dev_pairs_dir(),
            list(bags or []),
            out,
            core,
            evaluation.evaluation,
        )
    except ValueError as error:
        raise CommandError(str(error), 2) from None
    print_text('\n'.join([*lines, f'results: {out}']))
    return 0


main = alias(confidence, HELP, 'mlsemreg-confidence')
