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
``mlsemreg bench``: the paper's time table (appendix "Time cost analysis") on this machine.

The measurement is :mod:`mlsemreg_ros.evaluation.benchmark`. The pair is a real one
(``--pair``; default the first file of the KITTI dev pairs when present) or, without
data, a generated street scene with a known motion.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.core.config import metadata_errors, RegistrationConfig
from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    DATA,
    JsonOption,
    NoProgressOption,
    QuietOption,
    SetOption,
    settings,
)
import typer

HELP = (
    'Per-stage median time (ms per pair, both clouds) of the registration core for '
    '250..5000 keypoints per cloud, as in the appendix table of the paper ("Time cost '
    'analysis").'
)


def keypoint_counts(text: str) -> tuple[int, ...]:
    """``'250,500'`` -> ``(250, 500)``; a usage error unless positive integers."""
    try:
        counts = tuple(int(c) for c in text.split(',') if c.strip())
    except ValueError:
        raise typer.BadParameter(f'expects comma-separated integers, got {text!r}') from None
    if not counts:
        raise typer.BadParameter('needs at least one count')
    meta = RegistrationConfig.field_of('keypoints.count').metadata
    errors = [e for c in counts for e in metadata_errors('keypoints.count', c, meta)]
    if errors:
        raise typer.BadParameter('; '.join(errors))
    return counts


PairOption = Annotated[
    Path | None,
    typer.Option(
        '--pair',
        metavar='PATH',
        exists=True,
        dir_okay=False,
        help='pair file (.npz); default: the first KITTI dev pair if present, else a '
        'generated scene',
        rich_help_panel=DATA,
    ),
]
SyntheticOption = Annotated[
    bool,
    typer.Option(
        '--synthetic',
        help='use the generated scene even when real pairs are present',
        rich_help_panel=DATA,
    ),
]
RepeatsOption = Annotated[int, typer.Option(min=1, help='runs per size (median)')]
KeypointsOption = Annotated[str, typer.Option(help='comma-separated keypoint counts')]


def bench(
    pair_path: PairOption = None,
    synthetic: SyntheticOption = False,
    repeats: RepeatsOption = 5,
    keypoints: KeypointsOption = '250,500,1000,2500,5000',
    config: ConfigOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
    quiet: QuietOption = False,
    no_progress: NoProgressOption = False,
) -> int:
    """Per-stage median times of the registration core (alias mlsemreg-bench)."""
    from mlsemreg_ros.evaluation import benchmark, tables
    from mlsemreg_ros.evaluation.reports import write_json

    counts = keypoint_counts(keypoints)
    (core,) = settings((RegistrationConfig,), config, overrides)
    progress = not (quiet or no_progress)
    options = benchmark.BenchOptions(pair_path, synthetic, repeats, counts, progress)
    try:
        report = benchmark.benchmark_pair(options, core)
    except benchmark.BenchError as error:
        raise CommandError(str(error)) from None
    benchmark.print_benchmark(report)
    if json_path is not None:
        write_json(json_path, report.as_dict())
        tables.print_text(f'wrote {json_path}')
    return 0


main = alias(bench, HELP, 'mlsemreg-bench')
