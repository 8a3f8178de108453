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

"""The printed report of ``mlsemreg eval-pairs``: the pair table, the times, the baselines."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mlsemreg_ros.evaluation import tables
from mlsemreg_ros.evaluation.pairs import method_label


def print_pair_report(
    report: dict[str, Any], directory: Path, descriptor: str, core: Any, noise: Any
) -> str:
    """Print the pair table of ``evaluate_directory``'s report; return the method's label."""
    label = method_label(descriptor, core)
    noisy = f', label noise {noise}' if noise.active else ''
    tables.print_text(f'{label}, {len(report["pairs"])} pairs from {directory}{noisy}')
    tables.print_table(tables.pair_results_table(report['pairs'], report['summary']))
    stages = ', '.join(f'{k} {v:.0f}' for k, v in report['summary']['time_ms'].items())
    tables.print_text(f'mean time per pair (ms, both clouds): {stages}')
    return label


def print_comparison(label: str, report: dict[str, Any]) -> None:
    """Print the method ``label`` beside the baselines of ``report['baselines']``."""
    reports = {label: report, **report['baselines']}
    tables.print_text('\ncomparison on the same pairs (RE/TE: means over successful pairs):')
    tables.print_table(tables.comparison_table(reports))
    per_pair, legend = tables.per_pair_table(reports)
    tables.print_table(per_pair)
    tables.print_text(legend)
