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
The runs of ``mlsemreg eval-pairs`` and ``mlsemreg label-noise-sweep`` on a pair folder.

:func:`evaluate_pairs` registers every pair
(:func:`~mlsemreg_ros.evaluation.pairs.evaluate_directory`), prints the paper's table and
runs the pair baselines beside it (:mod:`mlsemreg_ros.evaluation.baselines`);
:func:`sweep_label_noise` runs the pairs at every label-noise level
(:mod:`mlsemreg_ros.evaluation.label_noise`, docs/label_noise.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlsemreg_ros.evaluation.label_noise import LabelNoise, sweep_row
from mlsemreg_ros.evaluation.pairs import evaluate_directory
from mlsemreg_ros.evaluation.settings import EvaluationConfig


@dataclass(frozen=True)
class PairEvalOptions:
    """What ``mlsemreg eval-pairs`` runs besides the configuration: descriptor, peers, noise."""

    descriptor: str = 'gedi'  # gedi: stored in the pair files; fpfh: computed at the keypoints
    baselines: tuple[str, ...] = ()  # pair baselines on the same pairs (evaluation/baselines.py)
    label_noise: str | None = None  # flip:F, confuse:C or both (evaluation/label_noise.py)
    noise_seed: int = 0
    progress: bool = True


def evaluate_pairs(
    directory: Path, options: PairEvalOptions, config: Any, bounds: EvaluationConfig
) -> dict[str, Any]:
    """
    Register every pair of ``directory``, print the paper's table, run and print the baselines.

    Returns the report of :func:`evaluate_directory` with the baselines' under ``baselines``.
    Raises :class:`~mlsemreg_ros.evaluation.label_noise.LabelNoiseError` (a bad
    ``label_noise``), :class:`~mlsemreg_ros.evaluation.pairs.EvalError` and
    :class:`~mlsemreg_ros.evaluation.baselines.BaselineUnavailable`.
    """
    from mlsemreg_ros.evaluation.baselines import run_baselines
    from mlsemreg_ros.evaluation.pair_report import print_comparison, print_pair_report

    noise = LabelNoise.parse(options.label_noise)
    report = evaluate_directory(
        directory, options.descriptor, config, bounds, progress=options.progress,
        label_noise=noise, noise_seed=options.noise_seed,
    )  # fmt: skip
    label = print_pair_report(report, directory, options.descriptor, config, noise)
    if options.baselines:
        report['baselines'] = run_baselines(
            directory, list(options.baselines), config, bounds, progress=options.progress
        )
        print_comparison(label, report)
    return report


def sweep_label_noise(
    directory: Any,
    descriptors: tuple[str, ...],
    levels: tuple[str, ...],
    config: Any,
    bounds: Any,
    noise_seed: int = 0,
) -> dict[str, Any]:
    """
    Run eval-pairs on ``directory`` at every level for every descriptor; print each row.

    Returns ``{'rows': [...], 'reports': {'<descriptor> <level>': report}}`` (sweep.json).
    Raises :class:`~mlsemreg_ros.evaluation.label_noise.LabelNoiseError` on a bad level
    before any pair runs.
    """
    from mlsemreg_ros.evaluation import tables

    noises = [(level, LabelNoise.parse(level)) for level in levels]
    rows, reports = [], {}
    for descriptor in descriptors:
        for level, noise in noises:
            report = evaluate_directory(
                directory, descriptor, config, bounds, progress=False, label_noise=noise,
                noise_seed=noise_seed,
            )  # fmt: skip
            reports[f'{descriptor} {level}'] = report
            row = sweep_row(descriptor, level, report)
            rows.append(row)
            right = round(row['rr_pct'] * row['pairs'] / 100)
            tables.print_text(
                f'{descriptor:5} {level:12} RR {row["rr_pct"]:5.1f} %  accepted '
                f'{row["accepted_right"]}/{right} right, {row["wrong_accepted"]} wrong  '
                f'IR {row["ir_pct"]:.2f} %'
            )
    return {'rows': rows, 'reports': reports}
