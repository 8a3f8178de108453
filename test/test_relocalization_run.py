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
``mlsemreg relocalize`` without the CLI: evaluation.relocalization's queries, scores, settings.

A map of the synthetic street (test/street_map.py) and two queries written here: one
between keyframes with its ground truth, one without; scored by hand-made answers too.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.maps.map_io import MapError
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from mlsemreg_ros.evaluation import relocalization as reloc
import numpy as np
import pytest
from street_map import STREET_SEED, write_street_map


def _found(T: np.ndarray | None, trials: int = 1, time_ms: float = 10.0) -> SimpleNamespace:
    """Return a stand-in relocalization answer (found when T is given)."""
    trial = SimpleNamespace(
        keyframe_id=0,
        similarity=0.9,
        accepted=T is not None,
        inliers=50,
        message='',
        time_ms=1.0,
        quick=False,
        deferred=False,
    )
    return SimpleNamespace(
        found=T is not None, T_map_sensor=T, keyframe_id=0 if T is not None else -1,
        trials=[trial] * trials, time_ms=time_ms, timings_ms={'search': 1.0},
    )  # fmt: skip


def test_score_and_summary_count_right_wrong_refused_and_unknown() -> None:
    truth = motion(0.0, (5.0, 0.0, 0.0))
    records = [
        reloc.score('right', _found(motion(1.0, (5.2, 0.0, 0.0))), truth),
        reloc.score('wrong', _found(motion(0.0, (6.0, 0.0, 0.0))), truth),  # TE 1 m
        reloc.score('refused', _found(None, trials=3), truth),
        reloc.score('no truth', _found(np.eye(4)), None),
    ]
    assert [r['verdict'] for r in records] == ['right', 'WRONG', 'refused', 'accepted']
    assert records[0]['te_m'] == pytest.approx(0.2) and records[0]['re_deg'] == pytest.approx(1.0)
    assert 'te_m' not in records[3] and records[2]['keyframe'] == -1
    summary = reloc.summarize(records)
    assert summary['queries'] == 4 and summary['with_ground_truth'] == 3
    assert summary['recall_pct'] == pytest.approx(100.0 / 3)
    assert (summary['accepted'], summary['wrong_accepted'], summary['refused']) == (3, 1, 1)
    assert summary['registrations_mean'] == 1.5 and summary['time_ms_p50'] == 10.0


def test_query_files_are_checked(tmp_path: Path) -> None:
    np.savez(tmp_path / 'a.npz', points=np.zeros((4, 3)))
    with pytest.raises(reloc.QueryError, match='needs points and labels'):
        reloc.read_query(tmp_path / 'a.npz')
    np.savez(tmp_path / 'b.npz', points=np.zeros((4, 2)), labels=np.zeros(4))
    with pytest.raises(reloc.QueryError, match=r'points must be \(N, 3\)'):
        reloc.read_query(tmp_path / 'b.npz')
    np.savez(tmp_path / 'c.npz', points=np.zeros((4, 3)), labels=np.zeros(3))
    with pytest.raises(reloc.QueryError, match=r'labels must be \(4,\)'):
        reloc.read_query(tmp_path / 'c.npz')
    (tmp_path / 'd.npz').write_text('not a zip')
    with pytest.raises(reloc.QueryError, match='cannot read'):
        reloc.read_query(tmp_path / 'd.npz')


def test_the_map_settings_come_first_unless_a_file_is_given(tmp_path: Path) -> None:
    stored = RegistrationConfig().replace({'semantic.top_k': 4})
    assert reloc.relocalization_config(stored, None) is stored
    assert reloc.relocalization_config(stored, None, ['keypoints.count=900']).semantic.top_k == 4
    assert reloc.relocalization_config(None, None, ['semantic.top_k=5']).semantic.top_k == 5
    with pytest.raises(ConfigError):
        reloc.relocalization_config(stored, None, ['semantic.nope=1'])
    with pytest.raises(ConfigError):
        reloc.relocalization_config(stored, tmp_path / 'missing.yaml')


def test_relocalize_queries_against_a_map_folder(tmp_path: Path) -> None:
    write_street_map(tmp_path / 'map')
    queries = tmp_path / 'queries'
    queries.mkdir()
    world, labels = street_scene(seed=STREET_SEED)
    truth = motion(-40.0, (7.0, -1.0, 0.0))  # between keyframes, turned
    points, scan_labels = scan_at(world, labels, truth, seed=999, max_points=15000)
    np.savez(queries / 'q0.npz', points=points, labels=scan_labels, T_map_scan=truth)
    np.savez(queries / 'q1.npz', points=points, labels=scan_labels)
    options = reloc.RelocalizeOptions(duplicate=2)
    report = reloc.relocalize_queries(tmp_path / 'map', queries, options)
    assert [r['verdict'] for r in report.records] == ['right', 'accepted']
    summary = report.summary
    assert summary['keyframes'] == 10 and summary['duplicate'] == 2  # five keyframes twice
    assert summary['recall_pct'] == 100.0 and summary['with_ground_truth'] == 1
    assert summary['map'] == str(tmp_path / 'map')
    assert set(report.as_dict()) == {'queries', 'summary'}
    first = reloc.relocalize_queries(
        tmp_path / 'map', queries, reloc.RelocalizeOptions(max_queries=1)
    )
    assert [r['query'] for r in first.records] == ['q0'] and first.summary['keyframes'] == 5
    with pytest.raises(reloc.QueryError, match=r'no \.npz query files'):
        reloc.relocalize_queries(tmp_path / 'map', tmp_path / 'map')
    with pytest.raises(MapError):
        reloc.relocalize_queries(queries, queries)
