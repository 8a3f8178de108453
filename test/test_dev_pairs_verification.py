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
Hypothesis verification on the real KITTI dev pairs (skipped without them).

Pair 000008 with our FPFH is on the edge: SC2-PCR's sampled graph of 700 correspondences
(``estimator.graph_size``) makes the street's mirror pose (169 deg) the hypothesis with
most inliers; verification on the dense labeled scans must bring the true pose back.

Pair 000007 with our FPFH has no hypothesis near the truth (54 inliers of 7902
correspondences, a slide along the street has ~100): the estimator's pose is refused and
the BEV search of the scans finds the truth.
"""

from dev_pairs import dev_pair_files, register_dev_pair
from mlsemreg_ros.datasets.pairs import load_pair
import pytest

pytestmark = pytest.mark.slow  # the real KITTI dev pairs at 5000 keypoints


def _register(path, verification: bool, descriptor: str = 'fpfh', **flat):
    flat = {'verification.enabled': verification, **flat}
    _, _, result, metrics = register_dev_pair(load_pair(path), descriptor, **flat)
    return result, metrics


@pytest.fixture(scope='module')
def pair_000008():
    paths = [p for p in dev_pair_files() if p.stem == '000008']
    if not paths:
        pytest.skip('dev pair 000008 not present')
    return paths[0]


def test_verification_rejects_the_mirror_pose_of_000008(pair_000008):
    # the landmarks of the paper (every landmark-class point): with confident landmarks only
    # (semantic.landmark_min_share, docs/label_noise.md) SC2-PCR picks the true pose itself
    paper = {'estimator.graph_size': 700, 'semantic.landmark_min_share': 0.0}
    _, plain_metrics = _register(pair_000008, False, **paper)
    assert not plain_metrics.success and plain_metrics.rotation_error_deg > 160.0
    verified, metrics = _register(pair_000008, True, **paper)
    assert metrics.success and metrics.rotation_error_deg < 1.0
    d = verified.diagnostics
    assert d['verification_switched'] and d['verification_chosen_rank'] > 0
    chosen = next(
        i
        for i in range(d['verification_hypotheses'])
        if d[f'verification_h{i}_rank'] == d['verification_chosen_rank']
    )
    # SC2-PCR ranked the mirror first (most inliers before refinement); on the dense scans
    # the true pose has far more overlap with agreeing labels
    assert d[f'verification_h{chosen}_score'] > 3.0 * d['verification_h0_score']
    assert (
        d[f'verification_h{chosen}_label_agreement'] > d['verification_h0_label_agreement'] + 0.05
    )
    # correspondence metrics do not depend on the chosen pose
    assert (metrics.inlier_number, metrics.n_correspondences) == (
        plain_metrics.inlier_number,
        plain_metrics.n_correspondences,
    )


def test_verification_keeps_every_default_success():
    for path in dev_pair_files():
        for descriptor in ('gedi', 'fpfh'):
            # a refused pose is refined on the downsampled source (fine.refused_downsampled)
            # and, once judged where both scans see, at a second distance too (the covisible
            # refinement): 000007 (GEDI, refused for its labels) ends at 0.42-0.48 deg
            # instead of 0.12-0.22, still a success. Both off here, so that the
            # verification's own effect is compared
            same = {'fine.refused_downsampled': False, 'covisibility.refine_distance': 0.0}
            _, plain = _register(path, False, descriptor, **same)
            _, verified = _register(path, True, descriptor, **same)
            if plain.success:
                assert verified.success, (path.stem, descriptor)
                assert verified.rotation_error_deg == pytest.approx(plain.rotation_error_deg)
            assert verified.inlier_number == plain.inlier_number


def test_the_bev_search_finds_000007_and_confidence_still_decides():
    paths = [p for p in dev_pair_files() if p.stem == '000007']
    if not paths:
        pytest.skip('dev pair 000007 not present')
    result, metrics = _register(paths[0], True)
    d = result.diagnostics
    # found by the BEV search, by the re-matching guided by its peaks (core/estimation/guided.py),
    # or by the polishing of the pool those fill (since the swapped and far searches, issue 30)
    assert d['chosen_origin'] in ('bev_search', 'guided', 'polished'), result.message
    assert metrics.success  # measured: RE 0.22 deg, TE 28 cm (refined by GICP)
    assert metrics.rotation_error_deg < 1.0 and metrics.translation_error_cm < 45.0
    # its labels disagree (building in one scan is vegetation in the other): label
    # agreement ~0.53 at the found pose, 0.57 at the truth, under the 0.6 the study needs
    assert d['confidence_overlap'] > 0.3
    if not result.success:
        assert 'label agreement' in result.message
    _, without = _register(paths[0], True, **{'bev_search.enabled': False})
    assert not without.success  # the estimator's own pose is a slide along the street


def test_000006_with_geometric_labels_measures_the_pool_it_judges(tmp_path):
    """
    The gate judges a replaced pool on its own covisible figures (regression, session 13).

    ``eval-pairs --descriptor fpfh --labels geometric`` on 000006: the labelled pool (67
    candidates) was measured by the covisible choice, then the pool was replaced by a
    smaller one (3); the gate's stage-9 measure read the old figures and raised (shapes
    (3,) and (67,)).
    """
    import json
    import os
    from pathlib import Path
    import subprocess
    import sys

    paths = [p for p in dev_pair_files() if p.stem == '000006']
    if not paths:
        pytest.skip('dev pair 000006 not present')
    folder = tmp_path / 'pairs'
    folder.mkdir()
    (folder / paths[0].name).symlink_to(paths[0].resolve())
    report = tmp_path / 'report.json'
    command = [sys.executable, '-m', 'mlsemreg_ros.tools.cli', 'eval-pairs', str(folder)]
    command += ['--descriptor', 'fpfh', '--labels', 'geometric', '--json', str(report)]
    root = str(Path(__file__).resolve().parents[1])  # the package as checked out
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([root, os.environ.get('PYTHONPATH', '')])}
    done = subprocess.run(
        [*command, '--quiet'], capture_output=True, text=True, timeout=600, env=env
    )
    assert done.returncode == 0, done.stderr[-2000:]
    (row,) = json.loads(report.read_text())['pairs']
    assert not row['accepted'] or row['success']  # never a wrong accepted pose
