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
The one results table of every tool (rich), and the tables built on it.

:class:`ResultTable` holds strings only; :func:`print_table` renders it with rich (on a
terminal fitted to its width, elsewhere at its natural width so logs never wrap a row).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math
from typing import Any

from mlsemreg_ros.evaluation.scoring import SUMMARY_KEYS, SUMMARY_UNITS


@dataclass
class ResultTable:
    """Header, rows and an optional footer row (after a rule), all as text."""

    headers: Sequence[str]
    rows: list[Sequence[str]] = field(default_factory=list)
    footer: Sequence[str] | None = None  # e.g. the mean line
    title: str | None = None
    left_columns: int = 1  # leading columns aligned left (the rest: right)


def cell(value: float | int | None, digits: int = 3) -> str:
    """Format a number: ints as they are, floats with ``digits``, '-' when missing."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '-'
    if isinstance(value, int) and not isinstance(value, bool):
        return f'{value:d}'
    return f'{value:.{digits}f}'


def render(table: ResultTable) -> Any:
    """Build the rich ``Table`` of a :class:`ResultTable`."""
    from rich import box
    from rich.table import Table

    out = Table(
        title=table.title,
        box=box.SIMPLE,
        show_edge=False,
        pad_edge=False,
        show_footer=table.footer is not None,
        title_justify='left',
    )
    for i, header in enumerate(table.headers):
        footer = table.footer[i] if table.footer is not None else ''
        widest = max([len(header), len(footer), *(len(row[i]) for row in table.rows)])
        out.add_column(
            header,
            justify='left' if i < table.left_columns else 'right',
            no_wrap=True,
            footer=footer,
            min_width=widest,  # never an ellipsis: the tables are read and parsed as text
        )
    for row in table.rows:
        out.add_row(*row)
    return out


def console(stderr: bool = False) -> Any:
    """Return a rich console on stdout (or stderr) that wraps nothing it prints."""
    from rich.console import Console

    return Console(stderr=stderr, soft_wrap=True, highlight=False)


def print_table(table: ResultTable) -> None:
    """Print a table on stdout: fitted on a terminal, at its natural width elsewhere."""
    from rich.measure import Measurement

    out = console()
    rich_table = render(table)
    width = None
    if not out.is_terminal:
        unbounded = out.options.update(max_width=10_000)  # measure beyond the 80 columns
        width = max(out.width, Measurement.get(out, unbounded, rich_table).maximum)
    out.print(rich_table, width=width, crop=False)


def print_text(text: str) -> None:
    """Print plain text on stdout (no markup, no wrapping): the tools' other output."""
    console().print(text, markup=False)


# -- the tables of the tools -------------------------------------------------------------
def sequence_summary_table(
    summary: dict[str, Any], method: str = 'value', others: dict[str, dict[str, Any]] | None = None
) -> ResultTable:
    """(metric, unit, value) of a sequence evaluation; ``others`` add columns by method."""
    columns = {method if others else 'value': summary, **(others or {})}
    return ResultTable(
        ['metric', 'unit', *columns],
        [
            [key, SUMMARY_UNITS[key], *(cell(s[key]) for s in columns.values())]
            for key in SUMMARY_KEYS
        ],
        left_columns=2,
    )


def pair_results_table(rows: list[dict[str, Any]], summary: dict[str, Any]) -> ResultTable:
    """Paper-style table: one line per pair and a mean line (RE/TE over successes only)."""
    lines = [
        [
            r['name'],
            str(r['n_correspondences']),
            str(r['inlier_number']),
            cell(r['inlier_ratio_pct'], 2),
            cell(r['rotation_error_deg'], 2),
            cell(r['translation_error_cm'], 1),
            'yes' if r['success'] else 'no',
            _accepted(r),
            cell(r['time_ms']['total_ms'], 0),
        ]
        for r in rows
    ]
    mean_corr = sum(r['n_correspondences'] for r in rows) / max(len(rows), 1)
    footer = [
        'mean',
        cell(mean_corr, 1),
        cell(summary['inlier_number'], 1),
        cell(summary['inlier_ratio_pct'], 2),
        cell(summary['rotation_error_deg'], 2),
        cell(summary['translation_error_cm'], 1),
        f'RR {cell(summary["registration_recall_pct"], 1)}%',
        f'{cell(summary.get("accepted_pct"), 0)}%',
        cell(summary['time_ms'].get('total_ms'), 0),
    ]
    return ResultTable(
        ('pair', '#corr', 'IN', 'IR %', 'RE deg', 'TE cm', 'success', 'accepted', 'total ms'),
        lines,
        footer,
    )


def _accepted(row: dict[str, Any]) -> str:
    """Return a pair's verdict (core/estimation/confidence.py); ``+bev``: a BEV search pose."""
    verdict = 'yes' if row.get('accepted', True) else 'no'
    return verdict + (' +bev' if row.get('bev_search') else '')


def comparison_table(reports: dict[str, dict[str, Any]]) -> ResultTable:
    """
    Side by side: one line per method (RR, RE, TE over successes, mean ms per pair).

    ``reports`` maps a method label to a report with ``pairs`` and ``summary``.
    """
    lines = []
    for label, report in reports.items():
        s = report['summary']
        lines.append(
            [
                label,
                cell(s['registration_recall_pct'], 1),
                cell(s['rotation_error_deg'], 2),
                cell(s['translation_error_cm'], 1),
                cell(s['time_ms'].get('total_ms'), 0),
                str(s['n_pairs']),
            ]
        )
    return ResultTable(('method', 'RR %', 'RE deg', 'TE cm', 'ms/pair', 'pairs'), lines)


def per_pair_table(reports: dict[str, dict[str, Any]]) -> tuple[ResultTable, str]:
    """Per pair and method: ``RE / TE`` and ``ok`` or ``--``; and the legend of the methods."""
    labels = list(reports)
    names = [row['name'] for row in reports[labels[0]]['pairs']]
    by_name = {label: {row['name']: row for row in reports[label]['pairs']} for label in labels}
    lines = []
    for name in names:
        cells = [name]
        for label in labels:
            row = by_name[label].get(name)
            cells.append(
                'n/a'
                if row is None
                else f'{cell(row["rotation_error_deg"], 2)} / '
                f'{cell(row["translation_error_cm"], 1)} '
                f'{"ok" if row["success"] else "--"}'
            )
        lines.append(cells)
    legend = '\n'.join(f'[{i + 1}] {label}' for i, label in enumerate(labels))
    headers = ('pair', *(f'[{i + 1}] RE deg / TE cm' for i in range(len(labels))))
    return ResultTable(headers, lines), legend
