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
``mlsemreg covariance-nees``: the NEES of the pose covariance per data set, before and after.

Data sets: the global registrations of pair files (``--pairs``), the pair chain streamed
through the odometry as scans 2 s apart (``--chain``), and bags of drives at strides
(``--drive D --stride S``). "Before" is the Hessian covariance times 7 (the scale before
the ``covariance`` section); "after" is the configuration's calibration. ``--fit`` grid
searches the scale, the floors and the correction terms, without the data sets named by
``--hold-out`` (docs/covariance.md). ``--samples DIR`` keeps the
samples, so a second run (another ``--set``, ``--fit``) does not register again.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import ConfigOption, JsonOption, SetOption, settings
import typer

HELP = 'NEES of the pose covariance on pairs, a pair chain and drives, before and after.'
#: The covariance scale before the calibration (odometry.covariance_scale, 2026-12-03).
SCALE_BEFORE = 7.0


def covariance_nees(
    pairs: Annotated[
        Path | None, typer.Option(help='folder of pair files: their global registrations')
    ] = None,
    chain: Annotated[
        Path | None, typer.Option(help='folder of chained pair files, streamed as scans')
    ] = None,
    drive: Annotated[
        list[Path] | None, typer.Option(help='bag of a drive with ground truth (repeatable)')
    ] = None,
    stride: Annotated[
        list[int] | None, typer.Option(help='strides of every drive (repeatable; default 1)')
    ] = None,
    samples: Annotated[
        Path | None, typer.Option(help='folder to keep the samples in (reused when present)')
    ] = None,
    fit: Annotated[bool, typer.Option(help='grid search the calibration')] = False,
    continuous: Annotated[
        bool, typer.Option(help='with --fit: a continuous search (differential evolution)')
    ] = False,
    hold_out: Annotated[
        list[str] | None,
        typer.Option(help='data sets whose name contains this are left out of --fit (repeatable)'),
    ] = None,
    config: ConfigOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
) -> int:
    """Print the NEES per data set with the uncalibrated and the configured covariance."""
    from mlsemreg_ros.core.alignment.covariance import no_calibration
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.datasets.pairs import list_pairs
    from mlsemreg_ros.evaluation import covariance_calibration as cc
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable

    (core,) = settings((RegistrationConfig,), config, overrides)
    jobs = []
    if pairs is not None:
        jobs.append(('pairs', lambda: cc.pair_samples(list_pairs(pairs), core)))
    if chain is not None:
        jobs.append(('chain', lambda: cc.stream_samples(cc.chain_scans(list_pairs(chain)), core)))
    for bag in drive or []:
        for step in stride or [1]:

            def run(bag: Path = bag, step: int = step) -> list:
                source = open_scan_source(bag)
                try:
                    return cc.stream_samples(source.scans(step), core)
                finally:
                    source.close()

            jobs.append((f'{bag.name} stride {step}', run))
    datasets = {}
    for name, job in jobs:
        cached = None if samples is None else samples / f'{name.replace(" ", "_")}.npz'
        if cached is not None and cached.exists():
            datasets[name] = cc.load_samples(cached)
            continue
        datasets[name] = job()
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            cc.save_samples(cached, datasets[name])
    scale, calibration = core.odometry.covariance_scale, core.covariance
    report: dict = {'bound_95': cc.NEES_BOUND_95, 'datasets': {}}
    rows = []
    for name, data in datasets.items():
        before = cc.nees_summary(cc.nees_values(data, SCALE_BEFORE, no_calibration()))
        after = cc.nees_summary(cc.nees_values(data, scale, calibration))
        report['datasets'][name] = {'before': before, 'after': after}
        held = any(part in name for part in hold_out or [])
        rows.append(
            [
                f'{name} (held out)' if held else name,
                str(after['samples']),
                f'{before["nees_mean"]:.1f}',
                f'{before["inside_95_pct"]:.0f}',
                f'{after["nees_mean"]:.1f}',
                f'{after["nees_median"]:.2f}',
                f'{after["inside_95_pct"]:.0f}',
            ]
        )
    print_table(
        ResultTable(
            (
                'data set',
                'samples',
                'before: mean',
                'inside 95 % bound %',
                'after: mean',
                'median',
                'inside 95 % bound %',
            ),
            rows,
            left_columns=1,
        )
    )
    fitted = {
        name: data
        for name, data in datasets.items()
        if not any(part in name for part in hold_out or [])
    }
    if fit and fitted:
        fitter = cc.fit_calibration_continuous if continuous else cc.fit_calibration
        best_scale, best, cost = fitter(fitted)
        report['fit'] = {
            'scale': best_scale,
            'covariance': vars(best),
            'cost': cost,
            'held_out': sorted(set(datasets) - set(fitted)),
        }
        grid = [name for name in cc.FIT_GRID if name != 'scale']
        values = ' '.join(f'covariance.{name}={getattr(best, name):g}' for name in grid)
        print_text(f'fit: odometry.covariance_scale={best_scale:g} {values} (cost {cost:.3f})')
    if json_path is not None:
        json_path.write_text(json.dumps(report, indent=2, default=float) + '\n')
    return 0
