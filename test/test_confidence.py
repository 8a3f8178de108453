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

"""Registration confidence: known answers, wrong registrations refused, the study tool."""

from __future__ import annotations

from pathlib import Path

from dev_pairs import dev_pair_files
from mlsemreg_ros.core.config import ConfidenceConfig, RegistrationConfig
from mlsemreg_ros.core.estimation.confidence import Evidence, refusal, tilt_deg
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene, synthetic_pair
from mlsemreg_ros.evaluation import confidence as study
from mlsemreg_ros.tools import confidence as confidence_tool
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bags import simulated_bag


def test_each_kind_of_evidence_can_refuse_on_its_own() -> None:
    config = ConfidenceConfig(
        min_inlier_ratio=0.01, min_overlap=0.2, min_label_agreement=0.6, max_tilt=30.0
    )
    good = Evidence(100, 2000, 0.4, 0.9, 2.0)
    assert refusal(good, config, 40) == ''
    cases = {
        'inliers < estimator.min_inliers=40': Evidence(30, 1000, 0.4, 0.9, 2.0),
        'inlier ratio 0.0050 < confidence.min_inlier_ratio': Evidence(50, 10000, 0.4, 0.9, 2.0),
        'overlap 0.100 < confidence.min_overlap': Evidence(100, 2000, 0.1, 0.9, 2.0),
        'label agreement 0.500 <': Evidence(100, 2000, 0.4, 0.5, 2.0),
        'tilt 175.0 deg > confidence.max_tilt': Evidence(100, 2000, 0.4, 0.9, 175.0),
        'tilt nan': Evidence(100, 2000, 0.4, 0.9, float('nan')),
    }
    for reason, evidence in cases.items():
        assert reason in refusal(evidence, config, 40), reason
    assert Evidence(0, 0, 0.0, 0.0, 0.0).inlier_ratio == 0.0
    flat = good.as_diagnostics()
    assert flat['confidence_inlier_ratio'] == 0.05 and flat['confidence_tilt_deg'] == 2.0


def test_tilt_is_the_turn_of_the_up_axis() -> None:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('zyx', [170.0, 0.0, 0.0], degrees=True).as_matrix()
    assert tilt_deg(T) < 1e-6  # any yaw keeps the up axis
    T[:3, :3] = Rotation.from_euler('x', 20.0, degrees=True).as_matrix()
    assert abs(tilt_deg(T) - 20.0) < 1e-9
    T[:3, :3] = Rotation.from_euler('x', 180.0, degrees=True).as_matrix()
    assert abs(tilt_deg(T) - 180.0) < 1e-6


def test_the_synthetic_pair_is_accepted_with_its_evidence() -> None:
    pair = synthetic_pair(seed=0)
    result = Registration().register_scans(
        pair.pts_src, pair.label_src, pair.pts_dst, pair.label_dst
    )
    assert result.success, result.message
    d = result.diagnostics
    assert d['confidence_overlap'] > 0.3 and d['confidence_label_agreement'] > 0.9
    assert d['confidence_tilt_deg'] < 2.0 and d['confidence_num_inliers'] >= 40


def test_scans_of_two_different_streets_are_refused() -> None:
    """Two streets of different worlds: whatever the estimator finds is not accepted."""
    here, there = street_scene(seed=11), street_scene(seed=12)
    a = scan_at(*here, np.eye(4), seed=1)
    b = scan_at(*there, motion(0.0, (10.0, 0.0, 0.0)), seed=2)
    result = Registration().register_scans(*b, *a)
    assert not result.success and result.message
    odometry = Odometry()
    odometry.process(*a)
    step = odometry.process(*b)
    assert not step.accepted and 'global registration failed' in step.reason


def test_a_cloud_mirrored_in_y_is_refused() -> None:
    pair = synthetic_pair(seed=2)
    mirrored = pair.pts_dst * np.array([1.0, -1.0, 1.0])
    result = Registration().register_scans(mirrored, pair.label_dst, pair.pts_dst, pair.label_dst)
    assert not result.success, (result.diagnostics['confidence_tilt_deg'], result.message)


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulated_bag(tmp_path_factory.mktemp('confidence') / 'sim', frames=6, seed=3)


def test_the_study_measures_simulated_pairs_and_writes_its_outputs(
    bag: Path, tmp_path: Path
) -> None:
    cases = study.sim_cases(bag, strides=(1, 4), per_stride=2)
    assert [c.kind for c in cases] == ['sim'] * 4
    rows = study.measure(cases, RegistrationConfig())
    assert all(r['right'] and r['accepted'] for r in rows), rows
    assert all(r['overlap'] > 0.3 and r['label_agreement'] > 0.9 for r in rows)
    lines = study.summary_lines(rows)
    assert lines[0].startswith('evidence') and any(line.startswith('sim ') for line in lines)
    out = tmp_path / 'out'
    assert (
        confidence_tool.main(
            ['--dev', str(tmp_path / 'none'), '--bags', str(bag), '--out', str(out)]
        )
        == 0
    )
    assert (out / 'evidence.png').stat().st_size > 10_000
    assert (out / 'evidence.csv').read_text().count('\n') == 1 + 8  # stride 1 only


def test_no_failure_case_of_the_dev_chain_is_published() -> None:
    """Far chain pairs and mirrors through the odometry: none published (issue 11)."""
    directory = dev_pair_files()[0].parent  # skips with the reason when absent
    streams = [s for s in study.stream_cases(directory) if s[0] in ('chain-far', 'mirror')]
    rows = study.run_streams(streams[::3], RegistrationConfig())
    assert sum(r['published'] for r in rows) == 0
