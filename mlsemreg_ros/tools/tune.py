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
``mlsemreg tune DATA``: tune the node's parameters on pair files or a bag with Optuna.

The engine is :mod:`mlsemreg_ros.evaluation.tuning`; this module is its command line:
the starting point (``--config``/``--set``, as eval-pairs), the space (``--space``), the
study (``--storage``, ``--study``, ``--workers``), then the progress, the table of the
Pareto trials, the plots and the tuned parameter file (``--out``). docs/tuning.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    configuration_error,
    DATA,
    LabelsOption,
    options_from,
    OUTPUT,
    PARAMETERS,
    QuietOption,
    replay_options,
    SetOption,
    settings,
    with_labels,
)
import typer

HELP = (
    'Tune the parameters on pair files or a bag with Optuna (accuracy against time, '
    'Pareto front; several workers share one study) and write the node parameter file.'
)
STUDY = 'Study'


DataArgument = Annotated[
    Path,
    typer.Argument(
        metavar='DATA', exists=True, help='folder of pair files (pairs) or a bag (bag)'
    ),
]
ObjectiveOption = Annotated[
    Literal['pairs', 'bag'],
    typer.Option(
        help='pairs: RR first, then RE/TE, against time per pair; bag: t_err and wrong '
        'poses against the latency ratio to KISS-ICP',
        rich_help_panel=DATA,
    ),
]
DescriptorOption = Annotated[
    Literal['gedi', 'fpfh'],
    typer.Option(help='pairs: as eval-pairs --descriptor', rich_help_panel=DATA),
]
StrideOption, MaxFramesOption = replay_options('bag: ')  # shared with eval-bag
TrialsOption = Annotated[
    int | None,
    typer.Option(
        min=0,
        help='trials to run now, shared by the workers (0: only write the result)',
        rich_help_panel=STUDY,
    ),
]
TimeoutOption = Annotated[
    float | None,
    typer.Option(min=1.0, help='stop starting trials after this many s', rich_help_panel=STUDY),
]
WorkersOption = Annotated[
    int,
    typer.Option(
        min=1, help='worker processes on this machine (one study)', rich_help_panel=STUDY
    ),
]
StorageOption = Annotated[
    str | None,
    typer.Option(
        metavar='URL',
        help='Optuna storage: sqlite:///x.db, postgresql://..., mysql://..., or '
        'journal:FILE (default: OUT with .db, SQLite)',
        rich_help_panel=STUDY,
    ),
]
StudyOption = Annotated[
    str,
    typer.Option(help='study name: an existing one is resumed or joined', rich_help_panel=STUDY),
]
SeedOption = Annotated[
    int, typer.Option(help='sampler seed (+ worker index)', rich_help_panel=STUDY)
]
SpaceOption = Annotated[
    list[str] | None,
    typer.Option(
        '--space',
        metavar='KEY=LOW:HIGH|A,B',
        help='narrow or add a searched parameter (repeatable), e.g. '
        '--space estimator.graph_size=100:1000 --space matcher.kind=nn,mnn',
        rich_help_panel=PARAMETERS,
    ),
]
OutOption = Annotated[
    Path,
    typer.Option(
        '--out',
        dir_okay=False,
        help='the tuned node parameter file; plots and the trials beside it',
        rich_help_panel=OUTPUT,
    ),
]


def tune(
    context: typer.Context,
    data: DataArgument,
    objective: ObjectiveOption = 'pairs',
    descriptor: DescriptorOption = 'gedi',
    stride: StrideOption = 1,
    max_frames: MaxFramesOption = None,
    trials: TrialsOption = 40,
    timeout: TimeoutOption = None,
    workers: WorkersOption = 1,
    storage: StorageOption = None,
    study: StudyOption = 'mlsemreg',
    seed: SeedOption = 0,
    space: SpaceOption = None,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    out: OutOption = Path('params.yaml'),
    quiet: QuietOption = False,
) -> int:
    """Tune the parameters with Optuna; write the node parameter file (alias mlsemreg-tune)."""
    import warnings

    from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.evaluation.tune_run import (
        tune_parameters,
        TuneConsole,
        TuneInputError,
        TuneOptions,
    )
    from mlsemreg_ros.parameter_docs import write_params_file
    from mlsemreg_ros.ros.node_config import NodeConfig
    import optuna

    warnings.filterwarnings('ignore', message='.*is experimental')
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    core, evaluation = settings(
        (RegistrationConfig, EvaluationSettings), config, with_labels(overrides, labels)
    )
    try:
        node_values = NodeConfig.from_file(config).to_flat_dict() if config is not None else {}
    except ConfigError as error:
        raise configuration_error(error) from None
    options = options_from(context, TuneOptions, timeout_s=timeout, space=tuple(space or ()))
    console = TuneConsole(quiet)
    try:
        result = tune_parameters(data, core, evaluation.evaluation, options, out, console)
    except TuneInputError as error:
        raise CommandError(str(error), 2) from None
    except RuntimeError as error:
        raise CommandError(str(error)) from None
    console.result(result)
    if result.chosen is None:
        raise CommandError(f'no trial completed; nothing written to {out}')
    write_params_file(out, result.values, node_values, result.header(out))
    console.written(result, out)
    return 0


main = alias(tune, HELP, 'mlsemreg-tune')
