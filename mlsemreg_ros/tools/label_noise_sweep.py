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
``mlsemreg label-noise-sweep DIR``: eval-pairs at every label-noise level, a table and a plot.

Each level is ``mlsemreg eval-pairs DIR --label-noise LEVEL`` (evaluation/label_noise.py);
docs/label_noise.md shows the result.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    configuration_error,
    SetOption,
)
import typer

HELP = (
    'Run eval-pairs on DIR at every label-noise level (flips 0/10/20/30 %, confusions '
    '10/30/50 %), both descriptors; print RR, accepted, wrong accepted and IR, write '
    'sweep.json and sweep.png.'
)


DirectoryArgument = Annotated[
    Path,
    typer.Argument(metavar='DIR', help='folder of pair files', exists=True, file_okay=False),
]
OutOption = Annotated[Path, typer.Option(help='results folder')]
LevelsOption = Annotated[
    list[str] | None, typer.Option('--level', help='noise levels (default: the sweep)')
]
DescriptorsOption = Annotated[
    list[str] | None, typer.Option('--descriptor', help='gedi and/or fpfh (default both)')
]
NoiseSeedOption = Annotated[int, typer.Option(min=0, help='seed of the label noise')]


def label_noise_sweep(
    directory: DirectoryArgument,
    out: OutOption = Path('results/label_noise'),
    levels: LevelsOption = None,
    descriptors: DescriptorsOption = None,
    noise_seed: NoiseSeedOption = 0,
    config: ConfigOption = None,
    overrides: SetOption = None,
) -> int:
    """Sweep the label noise (alias mlsemreg-label-noise-sweep)."""
    from mlsemreg_ros.core.config import ConfigError
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.label_noise import LabelNoiseError, plot_sweep, SWEEP
    from mlsemreg_ros.evaluation.pair_run import sweep_label_noise
    from mlsemreg_ros.evaluation.pairs import EvalError
    from mlsemreg_ros.evaluation.reports import write_json
    from mlsemreg_ros.tools.eval_pairs import build_settings

    chosen = tuple(descriptors or ('gedi', 'fpfh'))
    for descriptor in chosen:
        if descriptor not in ('gedi', 'fpfh'):
            raise CommandError(f'--descriptor {descriptor!r}: gedi or fpfh', 2)
    try:
        core, evaluation = build_settings(config, {}, list(overrides or []))
        sweep = sweep_label_noise(
            directory, chosen, tuple(levels or SWEEP), core, evaluation.evaluation, noise_seed
        )
    except (ConfigError, LabelNoiseError, OSError) as error:
        raise configuration_error(error) from None
    except EvalError as error:
        raise CommandError(str(error)) from None
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / 'sweep.json', sweep)
    plot_sweep(sweep['rows'], out / 'sweep.png')
    tables.print_text(f'wrote {out / "sweep.json"}, {out / "sweep.png"}')
    return 0


main = alias(label_noise_sweep, HELP, 'mlsemreg-label-noise-sweep')
