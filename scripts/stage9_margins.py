#!/usr/bin/env python3
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
Stage 9's margins (covisible acceptance, issues 30/34) from ``mlsemreg eval-pairs --json`` files.

For every pair of the files: accepted or not, right or wrong (the evaluation's bounds,
0.6 m / 5 deg), and, where stage 9 judged the pose, its tilt, the fine alignment's
``degeneracy_ratio``, its covisible overlap and how far its best distinct candidate and its
best slide stay below it. Then the counts (wrong accepted by any stage must be 0) and the
margins against ``covisibility.accept_overlap`` / ``accept_gap`` / ``accept_localizability``
(read from each file's config). Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/stage9_margins.py OUT/*.json [--rows]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def judged_rows(path: Path) -> list[dict[str, Any]]:
    """One row per pair of an eval-pairs JSON file, with stage 9's evidence where it ran."""
    report = json.loads(path.read_text())
    covis = report['config']['covisibility']
    rows = []
    for pair in report['pairs']:
        seen = pair.get('covisible') or {}
        row = {
            'file': path.stem,
            'pair': pair['name'],
            'accepted': bool(pair['accepted']),
            'right': bool(pair['success']),
            'by_stage9': bool(seen.get('covisible_accepted', False)),
            'judged': 'covisible_accept_tilt_deg' in seen,
            'tilt': seen.get('covisible_accept_tilt_deg'),
            'ratio': seen.get('degeneracy_ratio'),
            'overlap': seen.get('covisible_accept_overlap'),
            'refusal': seen.get('covisible_accept_refusal', ''),
            'floor': covis['accept_overlap'],
            'gap_needed': covis['accept_gap'],
            'localizability': covis.get('accept_localizability', 0.0),
        }
        if row['overlap'] is not None:
            rivals = ('covisible_accept_rival_overlap', 'covisible_accept_slide_overlap')
            rival = max(seen[key] for key in rivals)
            row['gap'] = row['overlap'] - rival
        rows.append(row)
    return rows


def _range(values: list[float]) -> str:
    return f'{min(values):.3f}-{max(values):.3f}' if values else '-'


def main() -> None:
    """Print the counts and margins (and with ``--rows`` every judged pose)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('files', nargs='+', type=Path)
    parser.add_argument('--rows', action='store_true', help='print every pose stage 9 judged')
    args = parser.parse_args()
    rows = [row for path in args.files for row in judged_rows(path)]
    wrong = [r for r in rows if r['accepted'] and not r['right']]
    print(
        f'{len(args.files)} files, {len(rows)} pairs: {sum(r["right"] for r in rows)} right, '
        f'{sum(r["accepted"] for r in rows)} accepted, {len(wrong)} wrong accepted '
        f'({sum(r["by_stage9"] for r in wrong)} by stage 9); stage 9 judged '
        f'{sum(r["judged"] for r in rows)}, accepted {sum(r["by_stage9"] for r in rows)}'
    )
    for r in wrong:
        print(f'  WRONG accepted: {r["file"]} {r["pair"]}')
    if args.rows:
        for r in rows:
            if r['judged']:
                gap = f'{r["gap"]:+.3f}' if 'gap' in r else '-'
                overlap = f'{r["overlap"]:.3f}' if r['overlap'] is not None else '-'
                ratio = f'{r["ratio"]:.4f}' if r['ratio'] is not None else '-'
                print(
                    f'{r["file"]:24s} {r["pair"]:24s} {"right" if r["right"] else "WRONG"} '
                    f'accepted={r["by_stage9"]!s:5s} overlap {overlap} gap {gap} '
                    f'tilt {r["tilt"]:.1f} ratio {ratio} {r["refusal"][:60]}'
                )
    right9 = [r for r in rows if r['by_stage9'] and r['right']]
    measured_wrong = [r for r in rows if r['judged'] and not r['right'] and 'gap' in r]
    print(
        f'right poses accepted by stage 9 ({len(right9)}): overlap '
        f'{_range([r["overlap"] for r in right9])}, gap {_range([r["gap"] for r in right9])}, '
        f'ratio {_range([r["ratio"] for r in right9 if r["ratio"] is not None])}'
    )
    print(
        f'wrong poses measured (tilt, level and localizability passed, {len(measured_wrong)}): '
        f'overlap {_range([r["overlap"] for r in measured_wrong])}; those at or above the '
        f'floor: '
        + (
            ', '.join(
                f'{r["pair"]} {r["overlap"]:.3f} gap {r["gap"]:+.3f}'
                for r in measured_wrong
                if r['overlap'] >= r['floor']
            )
            or 'none'
        )
    )


if __name__ == '__main__':
    main()
