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
The odometry's near-miss disputes of one ``mlsemreg eval-bag`` run, each basin against the truth.

Runs ``mlsemreg eval-bag`` with every verdict of the odometry's near-miss check recorded
(``core/alignment/near_miss.judge_basins`` as ``core/odometry/second_look.py`` calls it),
writes them to OUT/basins.json and prints one row per dispute ("two basins"): how far the
refined pose and its rival lie from the truth (relative to the keyframe's estimate), what
the lower residual, the higher inlier share and the nearer prediction pick, the recheck on
the deskewed sweep (``core/odometry/swept_dispute.py``) and what was published
(docs/confidence.md, session 19). Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/basin_disputes.py DRIVE --stride 5 \\
        --labels geometric --no-plots --quiet --output OUT
"""

from __future__ import annotations

import csv
import inspect
import json
from pathlib import Path
import sys
from typing import Any

from mlsemreg_ros.core.alignment import near_miss
from mlsemreg_ros.core.odometry import odometry, second_look, tracking
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

RECORDS: list[dict[str, Any]] = []
STATE: dict[str, Any] = {'frame': -1, 'prediction': None}


def _recorded() -> None:
    """Wrap the odometry's scan entry, its estimate and its basin verdicts to record them."""
    process, estimate = odometry.Odometry.process, tracking.Tracker.estimate

    def processed(self: Any, *args: Any, **kwargs: Any) -> Any:
        STATE['frame'], STATE['prediction'] = self._count, None
        return process(self, *args, **kwargs)

    def estimated(self: Any, current: Any, prediction: Any, *args: Any, **kwargs: Any) -> Any:
        if prediction is not None and not prediction.still:
            STATE['prediction'] = np.asarray(prediction.T_odom_current).tolist()
        return estimate(self, current, prediction, *args, **kwargs)

    def judged(refined: Any, align: Any, fit: Any, cfg: Any) -> Any:
        verdict = near_miss.judge_basins(refined, align, fit, cfg)
        caller = inspect.stack()[1:3]
        candidate = caller[0].frame.f_locals.get('candidate')
        RECORDS.append(
            {
                'frame': STATE['frame'],
                'caller': caller[1].function,
                'candidate': getattr(candidate, 'name', ''),
                'prediction': STATE['prediction'],
                'refusal': verdict.refusal,
                'refined': _basin(verdict.refined),
                'others': [_basin(b) for b in verdict.others],
            }
        )
        return verdict

    odometry.Odometry.process = processed
    tracking.Tracker.estimate = estimated
    second_look.judge_basins = judged


def _basin(basin: near_miss.Basin) -> dict[str, Any]:
    return {
        'T': np.asarray(basin.T_target_source).tolist(),
        'share': basin.inlier_fraction,
        'residual': basin.residual,
    }


def _poses(path: Path) -> list[np.ndarray]:
    rows = np.loadtxt(path, ndmin=2)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    return list(poses)


def _off(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    delta = np.linalg.solve(T_true, T)
    return float(np.linalg.norm(delta[:3, 3])), rotation_angle_deg(delta)


def _rival(basin: dict[str, Any], home: dict[str, Any], rival_share: float) -> bool:
    """Whether ``basin`` disputes ``home`` (judge_basins' rule with the default agreement)."""
    shift, turn = _off(np.array(basin['T']), np.array(home['T']))
    return (
        not (shift <= 0.4 and turn <= 1.0)
        and basin['share'] >= rival_share * home['share']
        and basin['residual'] * rival_share <= home['residual']
    )


def disputes(out: Path, rival_share: float = 0.95) -> list[str]:
    """Return the markdown rows of the run's disputes (``out``: the eval-bag results)."""
    with open(out / 'frames.csv') as f:
        frames = list(csv.DictReader(f))
    truth, estimate = _poses(out / 'ground_truth_kitti.txt'), _poses(out / 'trajectory_kitti.txt')
    by_bag = {int(f['bag_index']): int(f['frame']) for f in frames}
    records = json.loads((out / 'basins.json').read_text())
    rows = []
    for i, record in enumerate(records):
        if record['caller'] != '_near_miss' or 'two basins' not in record['refusal']:
            continue
        frame = frames[record['frame']]
        k, key = record['frame'], by_bag.get(int(frame['keyframe_index']), 0)
        T_true = estimate[key] @ np.linalg.solve(truth[key], truth[k])
        home = record['refined']
        T_home = np.array(home['T'])

        rival = next(b for b in record['others'] if _rival(b, home, rival_share))
        T_rival = np.array(rival['T'])
        home_off, rival_off = _off(T_home, T_true), _off(T_rival, T_true)
        nearer = 'refined' if home_off[0] < rival_off[0] else 'rival'
        picks = [
            'refined' if home['residual'] <= rival['residual'] else 'rival',
            'refined' if home['share'] >= rival['share'] else 'rival',
        ]
        if record['prediction'] is not None:
            P = np.array(record['prediction'])
            picks.append('refined' if _off(T_home, P)[0] <= _off(T_rival, P)[0] else 'rival')
        else:
            picks.append('-')
        later = records[i:]  # record i is the dispute itself
        again = next(
            (r for r in later if r['frame'] == k and r['caller'] == 'swept_refusal'), None
        )
        recheck = '-'
        if again is not None:
            swept = _off(np.array(again['refined']['T']), T_true)[0]
            recheck = f'{"disputed" if again["refusal"] else "one basin"} ({swept:.2f} m off)'
        published = 'refused'
        if frame['accepted'] == 'True':
            right = 'right' if frame['success'] == 'True' else 'WRONG'
            published = f'{right} {float(frame["te_cm"]):.1f} cm'
        marks = [p if p == '-' else f'{p} {"✓" if p == nearer else "✗"}' for p in picks]
        rows.append(
            f'| {k} ({frame["bag_index"]}) | {record["candidate"]} '
            f'| {home_off[0]:.2f} m / {home_off[1]:.1f}° '
            f'| {rival_off[0]:.2f} m / {rival_off[1]:.1f}° '
            f'| {_off(T_rival, T_home)[0]:.2f} m | {nearer} | {home["residual"]:.2f} / '
            f'{rival["residual"]:.2f} | {home["share"]:.3f} / {rival["share"]:.3f} | '
            f'{" | ".join(marks)} | {recheck} | {published} |'
        )
    return rows


def main() -> None:
    """Run eval-bag with the verdicts recorded, then print the disputes."""
    argv = sys.argv[1:]
    out = Path(argv[argv.index('--output') + 1])
    _recorded()
    from mlsemreg_ros.tools.cli import main as cli

    cli(['eval-bag', *argv])
    (out / 'basins.json').write_text(json.dumps(RECORDS))
    print(
        '| frame (bag) | candidate | refined pose off | rival off | apart | nearer the truth '
        '| residual refined / rival | share refined / rival | lower residual | higher share '
        '| nearer the prediction | recheck | published |'
    )
    print('|' + '---|' * 13)
    for row in disputes(out):
        print(row)


if __name__ == '__main__':
    main()
