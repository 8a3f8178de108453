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

import os
from pathlib import Path
import sys
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


def bench(
    pair_path: Annotated[
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
    ] = None,
    synthetic: Annotated[
        bool,
        typer.Option(
            '--synthetic',
            help='use the generated scene even when real pairs are present',
            rich_help_panel=DATA,
        ),
    ] = False,
    repeats: Annotated[int, typer.Option(min=1, help='runs per size (median)')] = 5,
    keypoints: Annotated[
        str, typer.Option(help='comma-separated keypoint counts')
    ] = '250,500,1000,2500,5000',
    config: ConfigOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
    quiet: QuietOption = False,
    no_progress: NoProgressOption = False,
) -> int:
    """Per-stage median times of the registration core (alias mlsemreg-bench)."""
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import first_dev_pair, load_pair
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.benchmark import bench_pair, generated_pair, timing_table
    from mlsemreg_ros.evaluation.reports import write_json
    import numpy

    counts = keypoint_counts(keypoints)
    (core,) = settings((RegistrationConfig,), config, overrides)
    path = None if synthetic else (pair_path or first_dev_pair())
    if path is not None:
        try:
            pair = load_pair(path)
        except (OSError, ValueError) as error:
            raise CommandError(f'cannot read {path}: {error}') from None
        if pair.kpts_src is None or pair.kpts_dst is None:
            raise CommandError(f'{path} has no keypoints (kpts_src/kpts_dst)')
        source_name = str(path)
    else:
        pair = generated_pair(keypoints=max(counts))
        source_name = 'generated street scene'
    available = min(len(pair.kpts_src), len(pair.kpts_dst))
    if max(counts) > available:
        tables.console(stderr=True).print(
            f'note: the pair has {available} keypoints per cloud; larger counts use all of them',
            markup=False,
        )
    rows = bench_pair(
        Registration(core), pair, counts, repeats, progress=not (quiet or no_progress)
    )
    load = ', '.join(f'{x:.1f}' for x in os.getloadavg())
    tables.print_text(
        f'pair: {source_name} ({len(pair.pts_src)} / {len(pair.pts_dst)} points); median of '
        f'{repeats} runs, ms per pair (both clouds); {os.cpu_count()} CPUs, load average '
        f'{load} (other work makes timings noisy)'
    )
    tables.print_table(timing_table(rows))
    tables.print_text(
        'Total-1 = Local-SS + BMR-SS + GM+MM (paper); BMR-SS includes landmark extraction; '
        'total = wall time of prepare x2 + register (keypoint lookup, FPFH, signatures, '
        'matching, estimator); total 2 threads = the same with both clouds prepared '
        'concurrently (Registration.prepare_scans).'
    )
    if json_path is not None:
        report = {
            'pair': source_name,
            'config': core.to_dict(),
            'keypoints': rows,
            'machine': {
                'cpu_count': os.cpu_count(),
                'numpy': numpy.__version__,
                'python': sys.version.split()[0],
                'load_average': list(os.getloadavg()),
            },
        }
        write_json(json_path, report)
        tables.print_text(f'wrote {json_path}')
    return 0


main = alias(bench, HELP, 'mlsemreg-bench')
