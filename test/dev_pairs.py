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
"""Where the real KITTI dev pairs live (never inside this repository)."""

import os
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEV_PAIRS = Path(
    os.environ.get('MLSEMREG_DEV_PAIRS', ROOT.parent / 'shared' / 'data' / 'kitti_pairs_dev')
)


def dev_pair_files() -> list[Path]:
    """Return the dev pair files, or skip the calling test with the reason."""
    files = sorted(DEV_PAIRS.glob('*.npz')) if DEV_PAIRS.is_dir() else []
    if not files:
        pytest.skip(
            f'real KITTI dev pairs not found in {DEV_PAIRS} (set MLSEMREG_DEV_PAIRS '
            'to their folder); the generated-scene tests cover this code without them'
        )
    return files


def register_dev_pair(pair: Any, descriptor: str = 'gedi', **flat: Any) -> tuple[Any, ...]:
    """
    Register a loaded pair (``datasets.pairs.PairData``) as stored, no voxelizing.

    ``descriptor``: 'gedi' uses the stored descriptors, 'fpfh' computes them; ``flat``:
    parameter overrides (``'section.key': value``). Returns the registration, the prepared
    source, the result and its metrics under ``trans_gt``.
    """
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.metrics import evaluate_pair
    from mlsemreg_ros.core.pipeline import Registration

    registration = Registration(RegistrationConfig().replace(flat))
    src_desc, dst_desc = pair.descriptors(descriptor) if descriptor != 'fpfh' else (None, None)
    source, target = registration.prepare_scans(
        *(
            {'points': p, 'labels': lab, 'keypoints': k, 'descriptors': d, 'voxelize': False}
            for p, lab, k, d in (
                (pair.pts_src, pair.label_src, pair.kpts_src, src_desc),
                (pair.pts_dst, pair.label_dst, pair.kpts_dst, dst_desc),
            )
        )
    )
    result = registration.register(source, target)
    metrics = evaluate_pair(
        result.transform, result.source_points, result.target_points, pair.trans_gt
    )
    return registration, source, result, metrics
