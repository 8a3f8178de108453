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
The gyro rescue's margin (core/odometry/gyro_rescue.py, issues 30/34) on any pair files.

Each pair goes through a fresh ``Odometry`` as ``mlsemreg fuzz-node`` sends it with an IMU
only (``test/test_gyro_rescue.py``): the target scan at t0, the source scan 1 s later, the
gyro of the true motion over that second (``hostile_cases.good_streams``), the points rounded
to float32 as the node receives them. The second scan has no prediction (no velocity yet),
so a refused global pose reaches the rescue. A spy on the rescue measures, for every refused
global pose it sees, whatever the bound: its angle to the gyro, the map's refinement of it
(trusted or not, the weak-direction rule) and the refined pose's angle to the gyro, and each
pose's error against the truth (right: 0.6 m / 5 deg). The real rescue then runs with the
configured bound. One JSON line per pair, then a summary. Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/gyro_margins.py DIR [DIR ...] \\
        [--keypoints 2000] [--set KEY=VALUE ...] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import time
from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import gyro_rescue, Odometry, review
from mlsemreg_ros.core.odometry.second_look import weak_refusal
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
from mlsemreg_ros.core.settings import parse_overrides
from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
from mlsemreg_ros.evaluation.hostile_cases import good_streams, Timeline
import numpy as np

RIGHT_M, RIGHT_DEG = 0.6, 5.0


def _error(truth: np.ndarray, pose: np.ndarray) -> tuple[float, float, bool]:
    """Translation (m) and rotation (deg) of ``pose`` from ``truth``, and whether right."""
    error = invert_transform(truth) @ pose
    metres, degrees = float(np.linalg.norm(error[:3, 3])), rotation_angle_deg(error)
    return metres, degrees, bool(metres <= RIGHT_M and degrees <= RIGHT_DEG)


class RescueSpy:
    """Wrap ``rescue_by_gyro``: measure the refused pose it is given, then call the rescue."""

    def __init__(self) -> None:
        self.truth: np.ndarray | None = None
        self.seen: dict[str, Any] | None = None
        self._rescue = gyro_rescue.rescue_by_gyro

    def __call__(
        self,
        odometry: Any,
        stamp_ns: int,
        prediction: Any,
        raw: Any,
        chosen: Any,
        timings: dict[str, float],
    ) -> Any:
        """Measure the refused pose the rescue is given (if it would look), then rescue."""
        result = chosen.result
        model = odometry.motion_model
        if (
            not chosen.accepted
            and prediction is None
            and result is not None
            and odometry.keyframe is not None
            and np.all(np.isfinite(result.transform))
        ):
            measured = model.gyro_rotation(stamp_ns)
            last = model.last_accepted
            if measured is not None and last is not None:
                self.seen = self._measure(odometry, raw, result, measured, last[0])
        return self._rescue(odometry, stamp_ns, prediction, raw, chosen, timings)

    def _measure(
        self, odometry: Any, raw: Any, result: Any, measured: np.ndarray, last_pose: np.ndarray
    ) -> dict[str, Any]:
        """The refused pose and its map refinement: angles to the gyro, errors, verdicts."""
        T_global = odometry.keyframe.pose @ result.transform
        candidate = odometry.tracker.candidate('global', T_global, raw.scan, odometry.config)
        refined = candidate.alignment.T_target_source
        m0, d0, right0 = _error(self.truth, T_global)
        m1, d1, right1 = _error(self.truth, refined)
        return {
            'refused_to_gyro_deg': gyro_rescue.gyro_disagreement_deg(
                last_pose, measured, T_global
            ),
            'refined_to_gyro_deg': gyro_rescue.gyro_disagreement_deg(last_pose, measured, refined),
            'refined_trusted': bool(candidate.acceptable),
            'weak_refusal': weak_refusal(candidate.alignment, odometry.config),
            'refused_error': [m0, d0],
            'refused_right': right0,
            'refined_error': [m1, d1],
            'refined_right': right1,
        }


def run_pair(path: Path, config: RegistrationConfig, spy: RescueSpy) -> dict[str, Any]:
    """The pair's two scans through a fresh odometry with an IMU only; the rescue's view."""
    pair = load_pair(path)
    odometry = Odometry(Registration(config))
    timeline = Timeline(1000.0, 1.0)
    imu = good_streams(pair.trans_gt, timeline)['imu']
    stamps = np.array([round(t * 1e9) for t, _ in imu], dtype=np.int64)
    gyro = np.stack([f['gyro'] for _, f in imu])
    odometry.motion_model.add_imu(stamps, gyro, np.tile([0.0, 0.0, 9.81], (len(stamps), 1)))
    t0, _, t2 = timeline.scans
    spy.truth, spy.seen = pair.trans_gt, None
    tic = time.perf_counter()
    odometry.process(pair.pts_dst.astype(np.float32), pair.label_dst, round(t0 * 1e9))
    step = odometry.process(pair.pts_src.astype(np.float32), pair.label_src, round(t2 * 1e9))
    row: dict[str, Any] = {
        'pair': path.stem,
        'set': path.parent.name,
        'distance_m': float(np.linalg.norm(pair.trans_gt[:3, 3])),
        'accepted': bool(step.accepted),
        'rescued': 'confirmed by the gyro' in (step.reason or ''),
        'seconds': time.perf_counter() - tic,
    }
    if step.accepted:
        m, d, right = _error(pair.trans_gt, step.pose)
        row.update(error=[m, d], right=right)
    if spy.seen is not None:
        row.update(spy.seen)
    return row


def main() -> None:
    """Run every pair of the folders; print one JSON line per pair and a summary."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('dirs', nargs='+', type=Path, help='pair folders or pair files')
    parser.add_argument('--keypoints', type=int, default=2000)
    parser.add_argument('--set', action='append', default=[], metavar='KEY=VALUE')
    parser.add_argument('--json', type=Path)
    args = parser.parse_args()
    overrides = {'keypoints.count': args.keypoints, **parse_overrides(args.set)}
    config = RegistrationConfig().replace(overrides)
    spy = RescueSpy()
    review.rescue_by_gyro = spy  # the reviewer calls the rescue through this name
    rows = []
    for directory in args.dirs:
        for path in [directory] if directory.is_file() else list_pairs(directory):
            row = run_pair(path, config, spy)
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    accepted = [r for r in rows if r['accepted']]
    wrong = [r for r in accepted if not r['right']]
    rescued = [r for r in rows if r['rescued']]
    print(
        f'{len(rows)} pairs: {len(accepted)} accepted ({len(rescued)} by the gyro), '
        f'{len(wrong)} wrong accepted'
    )
    for label, key in (('right', True), ('wrong', False)):
        seen = [r for r in rows if r.get('refined_right') is key]
        if seen:
            angles = sorted(r['refined_to_gyro_deg'] for r in seen)
            print(
                f'refined {label} poses: {len(seen)}, to the gyro {angles[0]:.2f}-'
                f'{angles[-1]:.2f} deg'
            )


if __name__ == '__main__':
    main()
