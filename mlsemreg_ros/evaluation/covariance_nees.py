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
The NEES of the pose covariance per data set, before and after: ``mlsemreg covariance-nees``.

:func:`covariance_nees` collects the samples of each data set (the global registrations of
pair files, the pair chain streamed as scans 2 s apart, bags of drives at strides; kept in
and reused from a samples folder), and summarises the NEES with the covariance before the
calibration (the Hessian times :data:`SCALE_BEFORE`) and with the configured one; with
``fit`` it grid searches the calibration without the held-out data sets
(``evaluation/covariance_calibration.py``, docs/covariance.md). :func:`print_nees` prints
the table and the fit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: The covariance scale before the calibration (odometry.covariance_scale, 2026-12-03).
SCALE_BEFORE = 7.0


@dataclass(frozen=True)
class NeesOptions:
    """The data sets, where their samples are kept, and the fit."""

    pairs: Path | None = None  # folder of pair files: their global registrations
    chain: Path | None = None  # folder of chained pair files, streamed as scans
    drives: tuple[Path, ...] = ()  # bags of drives with ground truth
    strides: tuple[int, ...] = (1,)  # the strides of every drive
    samples: Path | None = None  # folder of the samples (reused when present)
    fit: bool = False  # grid search the calibration
    hold_out: tuple[str, ...] = ()  # data sets whose name contains one are left out of the fit
    continuous: bool = False  # fit by a continuous search (differential evolution), not the grid

    def held_out(self, name: str) -> bool:
        """Whether data set ``name`` is left out of the fit."""
        return any(part in name for part in self.hold_out)


@dataclass
class NeesReport:
    """The NEES per data set (``before``, ``after``) and the fit; ``report``: the JSON."""

    options: NeesOptions
    report: dict[str, Any]


def _jobs(options: NeesOptions, core: Any) -> list[tuple[str, Callable[[], list]]]:
    """Each data set's name and the function that collects its samples."""
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.datasets.pairs import list_pairs
    from mlsemreg_ros.evaluation import covariance_calibration as cc

    jobs: list[tuple[str, Callable[[], list]]] = []
    pairs, chain = options.pairs, options.chain
    if pairs is not None:
        jobs.append(('pairs', lambda: cc.pair_samples(list_pairs(pairs), core)))
    if chain is not None:
        jobs.append(('chain', lambda: cc.stream_samples(cc.chain_scans(list_pairs(chain)), core)))
    for bag in options.drives:
        for step in options.strides:

            def run(bag: Path = bag, step: int = step) -> list:
                source = open_scan_source(bag)
                try:
                    return cc.stream_samples(source.scans(step), core)
                finally:
                    source.close()

            jobs.append((f'{bag.name} stride {step}', run))
    return jobs


def collect_samples(options: NeesOptions, core: Any) -> dict[str, list]:
    """Return each data set's samples, from ``options.samples`` when kept there before."""
    from mlsemreg_ros.evaluation import covariance_calibration as cc

    datasets = {}
    for name, job in _jobs(options, core):
        cached = (
            None if options.samples is None else options.samples / f'{name.replace(" ", "_")}.npz'
        )
        if cached is not None and cached.exists():
            datasets[name] = cc.load_samples(cached)
            continue
        datasets[name] = job()
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            cc.save_samples(cached, datasets[name])
    return datasets


def covariance_nees(options: NeesOptions, core: Any) -> NeesReport:
    """Return the NEES of every data set before and after the calibration, and the fit."""
    from mlsemreg_ros.core.alignment.covariance import no_calibration
    from mlsemreg_ros.evaluation import covariance_calibration as cc

    datasets = collect_samples(options, core)
    scale, calibration = core.odometry.covariance_scale, core.covariance
    report: dict = {'bound_95': cc.NEES_BOUND_95, 'datasets': {}}
    for name, data in datasets.items():
        before = cc.nees_summary(cc.nees_values(data, SCALE_BEFORE, no_calibration()))
        after = cc.nees_summary(cc.nees_values(data, scale, calibration))
        report['datasets'][name] = {'before': before, 'after': after}
    fitted = {name: data for name, data in datasets.items() if not options.held_out(name)}
    if options.fit and fitted:
        if options.continuous:
            best_scale, best, cost = cc.fit_calibration_continuous(
                fitted, start=(scale, calibration)
            )
        else:
            best_scale, best, cost = cc.fit_calibration(fitted)
        report['fit'] = {
            'scale': best_scale,
            'covariance': vars(best),
            'cost': cost,
            'held_out': sorted(set(datasets) - set(fitted)),
        }
    return NeesReport(options, report)


def print_nees(result: NeesReport) -> None:
    """Print the NEES table (before / after) and the fitted calibration."""
    from mlsemreg_ros.evaluation import covariance_calibration as cc
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable

    rows = []
    for name, summary in result.report['datasets'].items():
        before, after = summary['before'], summary['after']
        rows.append(
            [
                f'{name} (held out)' if result.options.held_out(name) else name,
                str(after['samples']),
                f'{before["nees_mean"]:.1f}',
                f'{before["inside_95_pct"]:.0f}',
                f'{after["nees_mean"]:.1f}',
                f'{after["nees_median"]:.2f}',
                f'{after["inside_95_pct"]:.0f}',
            ]
        )
    header = (
        'data set', 'samples', 'before: mean', 'inside 95 % bound %', 'after: mean', 'median',
        'inside 95 % bound %',
    )  # fmt: skip
    print_table(ResultTable(header, rows, left_columns=1))
    fit = result.report.get('fit')
    if fit is not None:
        best = fit['covariance']
        fitted = cc.FIT_BOUNDS if result.options.continuous else cc.FIT_GRID
        grid = [name for name in fitted if name != 'scale']
        values = ' '.join(f'covariance.{name}={best[name]:g}' for name in grid)
        print_text(
            f'fit: odometry.covariance_scale={fit["scale"]:g} {values} (cost {fit["cost"]:.3f})'
        )
