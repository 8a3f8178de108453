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
The node's latency benchmark: publish pairs to a running mlsemreg_node and time its answers.

Per pair: reset, then dst, src, dst, src, ... at a steady rate (every frame after the first
is a registration, alternately T and T^-1). Per frame:

- ``node_ms``: receipt of the scan in the node's callback -> publication of
  ``mlsemreg/transform``, measured inside the node (``latency_ms`` in ``/diagnostics``);
  this is the figure of the latency target (p50 <= 150 ms);
- ``e2e_ms``: the probe's ``publish()`` call -> receipt of the transform (adds DDS
  transport of the cloud and the executors' scheduling);
- ``processing_ms``: the core's share (prepare + register in
  ``core.odometry.Odometry.process``); ``node_ms - processing_ms`` is the ROS layer's
  overhead (conversion, hand-over, publishing).

The probe is :class:`mlsemreg_ros.ros.probe.NodeProbe` (duck-typed here: no rclpy import).
"""

from __future__ import annotations

import time
from typing import Any

from mlsemreg_ros.codec.poses import transform_message_to_matrix
from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.evaluation.settings import EvaluationConfig
from mlsemreg_ros.evaluation.tables import ResultTable
import numpy as np


def percentile(values: list[float], q: float) -> float:
    """Percentile (NaN when empty)."""
    return float(np.percentile(values, q)) if values else float('nan')


def bench_node_latency(
    pairs: list[Any], repeats: int, rate_hz: float, probe: Any, bounds: EvaluationConfig
) -> list[dict]:
    """Publish every pair as reset, dst, src, dst, ... at ``rate_hz``; one record per frame."""
    period, records, stamp_s = 1.0 / rate_hz, [], 1000.0
    for pair in pairs:
        if not probe.reset():
            raise RuntimeError('mlsemreg/reset did not answer')
        scans = [(pair.pts_dst, pair.label_dst), (pair.pts_src, pair.label_src)]
        which: dict[str, int] = {}  # stamp text -> 0 (dst) or 1 (src): to find the keyframe
        for frame in range(2 * repeats + 1):
            points, labels = scans[frame % 2]
            stamp_s += period
            stamp = probe.stamp(stamp_s)
            which[f'{stamp.sec + 1e-9 * stamp.nanosec:.9f}'] = frame % 2
            msg = probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp)
            tick = time.perf_counter()
            published = probe.publish(msg)
            status = probe.status_for(stamp, timeout=30.0)
            if frame > 0:
                found = probe.wait_until(lambda s=stamp: probe.find('transform', s), 0.5)
                records.append(
                    {
                        'pair': pair.name,
                        'frame': frame,
                        'node_ms': float(status['latency_ms'])
                        if status and 'latency_ms' in status
                        else None,
                        'e2e_ms': 1e3 * (found[0] - published) if found else None,
                        'processing_ms': float(status['processing_ms']) if status else None,
                        'success': found is not None,
                        **transform_errors(
                            found[1] if found else None,
                            pair.trans_gt,
                            frame % 2,
                            which.get((status or {}).get('keyframe_stamp', ''), 1 - frame % 2),
                            bounds,
                        ),
                        'stages_ms': {
                            k[6:]: float(v)
                            for k, v in (status or {}).items()
                            if k.startswith('stage.')
                        },
                    }
                )
            time.sleep(max(0.0, period - (time.perf_counter() - tick)))
    return records


def transform_errors(
    message: Any,
    truth: np.ndarray | None,
    current: int,
    keyframe: int,
    bounds: EvaluationConfig | None = None,
) -> dict[str, Any]:
    """
    RE (deg), TE (m) and success of a transform message against the pair's ground truth.

    ``current`` and ``keyframe`` say which scan each is (0 dst, 1 src): src onto a dst
    keyframe is ``trans_gt``, dst onto src its inverse, a scan onto itself the identity
    (after a rejected frame the keyframe stays).
    """
    if message is None or truth is None:
        return {}
    bounds = bounds or EvaluationConfig()
    estimate = transform_message_to_matrix(message.transform)
    expected = (
        np.eye(4) if current == keyframe else truth if current == 1 else invert_transform(truth)
    )
    rotation_error = rotation_error_deg(estimate[:3, :3], expected[:3, :3])
    translation_error = translation_error_m(estimate[:3, 3], expected[:3, 3])
    return {
        'rotation_error_deg': rotation_error,
        'translation_error_m': translation_error,
        'correct': bounds.succeeded(rotation_error, translation_error),
    }


def latency_summary(records: list[dict]) -> dict[str, Any]:
    """p50/p95/mean of node and end-to-end latency, stage medians, success rate."""
    out: dict[str, Any] = {
        'frames': len(records),
        'registered': sum(r['success'] for r in records),
        'correct': sum(r.get('correct', False) for r in records),
    }
    for key in ('node_ms', 'e2e_ms', 'processing_ms'):
        values = [r[key] for r in records if r[key] is not None]
        out[key] = {
            'p50': percentile(values, 50),
            'p95': percentile(values, 95),
            'mean': float(np.mean(values)) if values else float('nan'),
        }
    stages = sorted({k for r in records for k in r['stages_ms']})
    out['stage_p50_ms'] = {
        s: percentile([r['stages_ms'][s] for r in records if s in r['stages_ms']], 50)
        for s in stages
    }
    return out


def latency_table(result: dict[str, Any], bounds: EvaluationConfig) -> ResultTable:
    """(metric, unit, value) of :func:`latency_summary`."""
    rows = [
        ['frames registered', '', f'{result["registered"]}/{result["frames"]}'],
        [
            f'  of them RE <= {bounds.max_rotation_deg:g} deg, TE <= '
            f'{bounds.max_translation_m:g} m',
            '',
            f'{result["correct"]}/{result["frames"]}',
        ],
    ]
    for key, label in (
        ('node_ms', 'node latency'),
        ('e2e_ms', 'end-to-end latency'),
        ('processing_ms', 'core prepare+register'),
    ):
        rows += [[f'{label} {q}', 'ms', f'{result[key][q]:.1f}'] for q in ('p50', 'p95', 'mean')]
    rows += [
        [f'  stage {stage} p50', 'ms', f'{ms:.1f}'] for stage, ms in result['stage_p50_ms'].items()
    ]
    return ResultTable(('metric', 'unit', 'value'), rows, left_columns=2)
