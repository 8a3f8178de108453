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
The loop-closure peers of ``map build --baseline`` and ``relocalize --baseline``.

- the scoring of a peer's local-map loops against the ground truth (known answers);
- a 12-scan simulated drive through ``map build --baseline kiss-slam --baseline
  map-closures`` and ``relocalize --baseline map-closures`` (skipped without the peers);
- a missing peer stops the command with its install line.
"""

from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path

from mlsemreg_ros.evaluation import loop_peers, peer_runs
from mlsemreg_ros.tools import cli, relocalize, simulate
import numpy as np
import pytest


def _pose(x: float, y: float, yaw_deg: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = x, y
    return pose


def _out_and_back() -> loop_peers.LocalMapLoops:
    """Out 150 m along x and back 3.6 m to the left: four local maps of 75 scans."""
    out = [_pose(x, 0.0) for x in np.arange(0.0, 150.0, 1.0)]
    back = [_pose(x, 3.6, 180.0) for x in np.arange(150.0, 0.0, -1.0)]
    truth = out + back
    run = loop_peers.LocalMapLoops('peer', [0, 75, 150, 225], truth=truth)
    run.stamps_ns = [100_000_000 * i for i in range(len(truth))]  # 10 Hz
    run.poses_odometry = run.poses_loops = np.stack(truth)
    return run


def test_local_map_loops_are_scored_against_the_ground_truth() -> None:
    run = _out_and_back()
    truth = np.stack(run.truth)
    exact = np.linalg.inv(truth[150]) @ truth[75]  # T_query_reference, map 2 onto map 1
    off = exact.copy()
    off[0, 3] += 1.0
    run.proposed = [(1, 2, exact, True), (0, 3, off, True), (0, 2, exact, False)]
    summary = loop_peers.score_local_map_loops(run)
    assert summary['proposed'] == 3 and summary['closed'] == 2
    assert summary['right'] == 1 and summary['wrong'] == 1
    assert summary['precision_pct'] == pytest.approx(50.0)
    # in the peer's own unit: maps 2 and 3 come back along maps 1 and 0; map 2 onto map 1
    # only is right
    assert summary['unit_revisits'] == 2 and summary['unit_recall_pct'] == pytest.approx(50.0)
    # in the one unit of every method: the way back is one revisit from scan 163 (x = 137 m,
    # 4.7 m from x = 134 m passed 31.7 m before) to the end, 14 places of 10 m; map 2's scans
    # (150-224) hold the first 7 of them
    assert summary['revisits'] == 1 and summary['revisits_found'] == 1
    assert summary['recall_pct'] == pytest.approx(100.0)
    assert summary['places'] == 14 and summary['places_found'] == 7
    assert summary['place_recall_pct'] == pytest.approx(50.0)
    edges = summary['loop_edges']
    assert edges[0]['right'] and edges[0]['te_m'] < 1e-9
    assert not edges[1]['right'] and edges[1]['te_m'] == pytest.approx(1.0)
    assert edges[1]['same_place']  # right place, pose beyond the bound
    assert summary['ate_loops_m'] == pytest.approx(0.0, abs=1e-9)


def test_revisits_are_runs_of_scans_back_within_5_m_after_30_m_of_travel() -> None:
    run = _out_and_back()
    stamps = np.asarray(run.stamps_ns)
    positions = np.stack(run.truth)[:, :3, 3]
    scan = 100_000_000
    assert loop_peers.revisit_segments(stamps, positions) == [(163 * scan, 299 * scan)]
    places = loop_peers.revisit_segments(stamps, positions, place_m=10.0)
    assert places[0] == (163 * scan, 172 * scan) and places[-1] == (293 * scan, 299 * scan)
    assert loop_peers.revisit_segments(stamps[:150], positions[:150]) == []  # out only
    # a revisit is found by a query holding one of its scans, not by one beside it
    assert loop_peers.segments_found(places, [(172 * scan, 173 * scan)]) == 2
    assert loop_peers.segments_found(places, [(100 * scan, 162 * scan)]) == 0


def test_our_keyframe_loops_count_in_the_same_revisits() -> None:
    """A right loop finds the revisit holding its current keyframe's scan; a wrong one none."""
    scan = 100_000_000
    revisits = {'segments': [(10 * scan, 40 * scan)], 'places': [(10 * scan, 20 * scan)]}
    edges = [
        {'current': 5, 'current_stamp_ns': 25 * scan, 'right': True},
        {'current': 6, 'current_stamp_ns': 15 * scan, 'right': False},
    ]
    build = {
        'scans': 50, 'keyframes': 9, 'loops': 2, 'loop_edges': edges, 'loops_wrong': 1,
        'revisits': 4, 'revisit_segments': revisits,
    }  # fmt: skip
    ours = loop_peers.ours_loop_summary(build, 1.0)
    assert ours['revisits'] == 1 and ours['revisits_found'] == 1
    assert ours['places'] == 1 and ours['places_found'] == 0  # the right loop is at 25
    assert ours['unit_revisits'] == 4 and ours['unit_recall_pct'] == pytest.approx(25.0)


def test_the_revisit_diagnosis_says_where_our_loop_closure_stops() -> None:
    """Per revisit: keyframes, tried at the same place, registered, closed right."""
    from mlsemreg_ros.evaluation.map_build import revisit_diagnosis

    trials = [
        {'keyframe': 1, 'stamp_ns': 5, 'tried': [], 'tried_distance_m': [], 'closed': False},
        {'keyframe': 2, 'stamp_ns': 11, 'tried': [], 'tried_distance_m': [], 'closed': False},
        {'keyframe': 3, 'stamp_ns': 12, 'tried': [0], 'tried_distance_m': [40.0], 'closed': False},
        {'keyframe': 4, 'stamp_ns': 13, 'tried': [0], 'tried_distance_m': [3.0], 'closed': False},
        {'keyframe': 5, 'stamp_ns': 14, 'tried': [0], 'tried_distance_m': [2.0], 'closed': True},
    ]
    summary = {
        'revisit_segments': {'segments': [(10, 20)], 'places': []},
        'keyframe_trials': trials,
        'loop_edges': [{'current': 5, 'right': True}],
        'loops_refused': [{'current': 4, 'right': True}],
    }
    assert revisit_diagnosis(summary) == [
        {
            'first_stamp_ns': 10, 'last_stamp_ns': 20, 'keyframes': 4, 'tried': 3,
            'tried_same_place': 2, 'registered': 2, 'closed_right': 1, 'closed_wrong': 0,
        }
    ]  # fmt: skip


def test_without_ground_truth_a_peer_run_is_only_counted() -> None:
    run = _out_and_back()
    run.truth[5] = None
    summary = loop_peers.score_local_map_loops(run)
    assert summary['local_maps'] == 4 and 'right' not in summary


def test_a_numpy_verdict_of_kiss_slam_scores_as_plain_json() -> None:
    """KISS-SLAM's overlap test answers a numpy bool: the summary must stay plain JSON."""
    run = _out_and_back()
    truth = np.stack(run.truth)
    exact = np.linalg.inv(truth[150]) @ truth[75]
    run.proposed = [(1, 2, exact, np.bool_(True)), (0, 2, exact, np.bool_(False))]
    summary = loop_peers.score_local_map_loops(run)
    assert summary['closed'] == 1 and type(summary['closed']) is int
    json.dumps(summary)  # issue 32: 'int64 is not JSON serializable' at the end of a run


def test_every_json_of_the_cli_takes_numpy_values(tmp_path: Path) -> None:
    from mlsemreg_ros.evaluation.reports import write_json

    report = {
        'closed': np.int64(3),
        'good': np.bool_(True),
        'ate': np.float64(0.5),
        'none': np.float32('nan'),
        'pose': np.eye(2),
        'pair': (np.int32(1), Path('a/b')),
        7: [np.uint8(2)],
    }
    path = tmp_path / 'deep' / 'report.json'
    write_json(path, report)
    assert json.loads(path.read_text()) == {
        'closed': 3, 'good': True, 'ate': 0.5, 'none': None, 'pose': [[1.0, 0.0], [0.0, 1.0]],
        'pair': [1, 'a/b'], '7': [2],
    }  # fmt: skip


@pytest.fixture(scope='module')
def plain_drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('plain_drive') / 'sim'
    assert simulate.main([str(out), '--frames', '6', '--seed', '0', '--quiet']) == 0
    return out


def test_map_build_writes_its_json_with_the_peers_numpy_summaries(
    plain_drive: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``map build --baseline ... --json``: the peers' summaries hold numpy scalars (issue 32)."""
    from mlsemreg_ros.evaluation import map_build

    def numpy_peers(*args: object) -> dict:
        return {'kiss-slam': {'closed': np.int64(2), 'right': np.int64(1), 'ok': np.bool_(1)}}

    monkeypatch.setattr(peer_runs, 'require_peers', lambda names: None)
    monkeypatch.setattr(map_build, 'compare_loops', numpy_peers)
    report = tmp_path / 'build.json'
    args = ['map', 'build', str(plain_drive), str(tmp_path / 'map'), '--quiet', '--json',
            str(report), '--baseline', 'kiss-slam', '--set', 'keypoints.count=1000']  # fmt: skip
    assert cli.main(args) == 0
    written = json.loads(report.read_text())
    assert written['baselines'] == {'kiss-slam': {'closed': 2, 'right': 1, 'ok': True}}
    assert written['scans'] == 6


@pytest.fixture(scope='module')
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    missing = peer_runs.missing_peers(list(loop_peers.LOOP_PEERS))
    if missing:
        pytest.skip(f'loop peers not installed: {missing}')
    out = tmp_path_factory.mktemp('loop_peers') / 'sim'
    assert simulate.main([str(out), '--frames', '12', '--seed', '0', '--quiet']) == 0
    return out


def test_map_build_runs_both_loop_peers_on_the_same_scans(
    drive: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, report = drive.parent / 'map', drive.parent / 'build.json'
    args = ['map', 'build', str(drive), str(out), '--quiet', '--json', str(report)]
    args += [
        '--set',
        'keypoints.count=1500',
        '--baseline',
        'kiss-slam',
        '--baseline',
        'map-closures',
    ]
    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    assert 'KISS-SLAM' in printed and 'MapClosures' in printed and 'recall %' in printed
    assert 'iteration=' not in printed  # g2o's own prints are silenced
    baselines = json.loads(report.read_text())['baselines']
    assert set(baselines) == {'ours', 'kiss-slam', 'map-closures'}
    for name in ('kiss-slam', 'map-closures'):
        peer = baselines[name]
        assert peer['scans'] == 12 and peer['local_maps'] == 1
        assert peer['closed'] == 0 and peer['wrong'] == 0
        assert peer['ate_odometry_m'] < 0.2 and peer['ate_loops_m'] < 0.2, name
    assert baselines['ours']['scans'] == 12 and baselines['ours']['wrong'] == 0
    for summary in baselines.values():  # one count of the ground truth's revisits for all
        assert summary['revisits'] == 0 and summary['recall_pct'] is None


def test_the_peers_local_map_size_is_theirs_to_set(drive: Path) -> None:
    """``map build --peer-local-map``: both peers cut a new local map that far from the last."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.datasets.factory import open_scan_source

    source = open_scan_source(drive)
    travel = np.linalg.norm(np.diff([s.pose[:3, 3] for s in source.scans()], axis=0), axis=1)
    source.close()
    split_m = float(travel.sum()) / 4.0
    peers = loop_peers.run_loop_peers(
        lambda: open_scan_source(drive), list(loop_peers.LOOP_PEERS), None,
        RegistrationConfig().map, split_m,
    )  # fmt: skip
    for name, peer in peers.items():  # a straight drive: three or four local maps, not one
        assert peer['scans'] == 12 and 3 <= peer['local_maps'] <= 4, (name, peer)
        assert peer['closed'] == 0 and peer['ate_odometry_m'] < 0.2, name


def test_relocalize_compares_with_map_closures_as_place_recognition(
    drive: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, queries = drive.parent / 'map_gt', drive.parent / 'queries'
    assert (
        cli.main(['map', 'build', str(drive), str(out), '--poses', 'ground-truth', '--quiet']) == 0
    )
    assert (
        cli.main(['map', 'queries', str(drive), str(queries), '--every', '3', '--start', '1']) == 0
    )
    capsys.readouterr()
    report = drive.parent / 'reloc.json'
    args = [str(out), str(queries), '--baseline', 'map-closures', '--json', str(report),
            '--set', 'keypoints.count=1500']  # fmt: skip
    assert relocalize.main(args) == 0
    assert 'MapClosures as place recognition' in capsys.readouterr().out
    peer = json.loads(report.read_text())['baselines']['map-closures']
    assert peer['summary']['queries'] == 4
    for record in peer['queries']:  # a pose from the keyframe it matched, T convention right
        if record['accepted']:
            assert record['te_m'] < 1.5, record


def test_a_missing_loop_peer_is_named_with_its_install_line(
    tmp_path: Path, not_installed: Callable[[str], None], capsys: pytest.CaptureFixture[str]
) -> None:
    not_installed('map_closures')
    out = tmp_path / 'map'
    assert (
        cli.main(['map', 'build', str(tmp_path / 'bag'), str(out), '--baseline', 'kiss-slam']) == 2
    )
    err = capsys.readouterr().err
    assert 'map-closures' in err and '--no-deps' in err
    assert not out.exists()  # stopped before anything ran
    queries = ['relocalize', str(tmp_path), str(tmp_path), '--baseline', 'map-closures']
    assert cli.main(queries) == 2 and 'map-closures' in capsys.readouterr().err
