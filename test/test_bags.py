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

"""Bags and sequence folders: rosbag2 round trips, the KITTI converter, the simulator CLI."""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.codec.pose_files import (
    read_kitti_poses,
    read_tum_poses,
    write_kitti_poses,
    write_tum_poses,
)
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.rigid import relative_transform
from mlsemreg_ros.datasets.bag import BagScanReader, BagWriter, read_poses
from mlsemreg_ros.datasets.factory import open_scan_source
from mlsemreg_ros.datasets.kitti import KittiSequence
from mlsemreg_ros.datasets.source import ScanSource, SourceError
from mlsemreg_ros.simulation.trajectory import euler_to_matrix
from mlsemreg_ros.tools import kitti_to_bag, simulate
import numpy as np
import pytest

LABELS = LabelMap.load()
START_NS = 1_700_000_000 * 10**9


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4, 4) random rigid transforms."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = euler_to_matrix(*rng.uniform(-np.pi, np.pi, size=(3, n)))
    poses[:, :3, 3] = rng.uniform(-50, 50, size=(n, 3))
    return poses


def random_cloud(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Draw xyz (float32-exact), raw labels with instance bits and intensity."""
    xyz = rng.uniform(-80, 80, size=(n, 3)).astype(np.float32).astype(np.float64)
    learning = rng.integers(0, LABELS.num_classes, n)
    instance = np.where(np.isin(learning, [1, 4]), rng.integers(1, 2000, n), 0)
    raw = LABELS.to_raw(learning, instance)
    intensity = rng.uniform(0, 1, n).astype(np.float32)
    return xyz, raw, intensity


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_round_trip_of_clouds_and_odometry(tmp_path: Path, storage: str) -> None:
    rng = np.random.default_rng(0)
    poses = random_poses(rng, 4)
    clouds = [random_cloud(rng, int(n)) for n in (100, 1, 2500, 37)]
    stamps = START_NS + 100_000_000 * np.arange(4)
    bag = tmp_path / 'bag'
    with BagWriter(bag, storage=storage) as writer:
        for stamp, (xyz, raw, intensity), pose in zip(stamps, clouds, poses, strict=True):
            writer.write_cloud(int(stamp), xyz, raw, intensity, frame_id='velodyne')
            writer.write_odometry(int(stamp), pose)
    source = open_scan_source(bag)
    assert isinstance(source, BagScanReader) and isinstance(source, ScanSource)
    assert len(source) == 4 and source.points_topic == '/points'
    scans = list(source.scans())
    source.close()
    assert [s.index for s in scans] == [0, 1, 2, 3]
    for scan, stamp, (xyz, raw, intensity), pose in zip(scans, stamps, clouds, poses, strict=True):
        assert scan.stamp_ns == stamp and scan.frame_id == 'velodyne'
        np.testing.assert_array_equal(scan.xyz, xyz)
        np.testing.assert_array_equal(scan.labels, raw.astype(np.int64))
        np.testing.assert_array_equal(scan.intensity, intensity)
        np.testing.assert_allclose(scan.pose, pose, atol=1e-12)
    assert np.array_equal(
        LABELS.to_learning(scans[2].labels, 'raw'), LABELS.to_learning(clouds[2][1], 'raw')
    )
    gt_stamps, gt_poses = read_poses(bag, '/ground_truth/odometry')
    np.testing.assert_array_equal(gt_stamps, stamps)
    np.testing.assert_allclose(gt_poses, poses, atol=1e-12)
    strided = list(BagScanReader(bag, gt_topic=None).scans(stride=2, max_frames=5))
    assert [s.index for s in strided] == [0, 2] and strided[0].pose is None


def test_bag_reader_errors_name_what_exists(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    with BagWriter(bag, storage='sqlite3') as writer:
        writer.write_cloud(START_NS, np.zeros((3, 3)), topic='/a')
        writer.write_cloud(START_NS, np.zeros((3, 3)), topic='/b')
    with pytest.raises(SourceError, match='/a'):
        BagScanReader(bag)
    with pytest.raises(SourceError, match="'/c'"):
        BagScanReader(bag, points_topic='/c')
    with pytest.warns(UserWarning, match='no .label. field'):
        scans = list(BagScanReader(bag, points_topic='/a').scans())
    assert scans[0].labels is None
    with pytest.raises(SourceError, match='neither'):
        open_scan_source(tmp_path)


def test_pose_files_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    poses = random_poses(rng, 5)
    write_kitti_poses(tmp_path / 'p.txt', poses)
    np.testing.assert_allclose(read_kitti_poses(tmp_path / 'p.txt'), poses, atol=1e-8)
    stamps = START_NS + np.array([0, 1, 99_999_999_999, 3, 4])
    write_tum_poses(tmp_path / 't.txt', stamps, poses)
    seconds, back = read_tum_poses(tmp_path / 't.txt')
    np.testing.assert_allclose(back, poses, atol=1e-8)
    assert abs(seconds[2] - stamps[2] / 1e9) < 1e-6


def write_fake_kitti(
    root: Path, rng: np.random.Generator, frames: int = 3, labels: bool = True
) -> dict:
    """Write a tiny SemanticKITTI-shaped sequence folder; return what was written."""
    (root / 'velodyne').mkdir(parents=True)
    if labels:
        (root / 'labels').mkdir()
    clouds, raws = [], []
    for k in range(frames):
        n = 50 + 10 * k
        data = rng.uniform(-30, 30, size=(n, 4)).astype(np.float32)
        data[:, 3] = rng.uniform(0, 1, n)
        data.tofile(root / 'velodyne' / f'{k:06d}.bin')
        raw = LABELS.to_raw(rng.integers(0, LABELS.num_classes, n), rng.integers(0, 5, n))
        if labels:
            raw.astype('<u4').tofile(root / 'labels' / f'{k:06d}.label')
        clouds.append(data)
        raws.append(raw)
    camera = random_poses(rng, frames)
    camera = relative_transform(camera[0], camera)
    write_kitti_poses(root / 'poses.txt', camera)
    tr = random_poses(rng, 1)[0]
    calib = '\n'.join(
        [f'P{i}: ' + ' '.join(['0.0'] * 12) for i in range(4)]
        + ['Tr: ' + ' '.join(f'{v:.12e}' for v in tr[:3, :4].ravel())]
    )
    (root / 'calib.txt').write_text(calib + '\n')
    times = np.array([0.0, 0.103, 0.2051][:frames])
    np.savetxt(root / 'times.txt', times, fmt='%.6e')
    return {'clouds': clouds, 'raws': raws, 'camera': camera, 'tr': tr, 'times': times}


def test_kitti_converter_on_a_fake_sequence(tmp_path: Path) -> None:
    fake = write_fake_kitti(tmp_path / 'seq' / '08', np.random.default_rng(2))
    out = tmp_path / 'bag'
    assert kitti_to_bag.main([str(tmp_path / 'seq' / '08'), str(out), '--quiet']) == 0
    lidar_poses = np.linalg.inv(fake['tr']) @ fake['camera'] @ fake['tr']
    np.testing.assert_allclose(lidar_poses[0], np.eye(4), atol=1e-9)
    source = open_scan_source(out)
    scans = list(source.scans())
    source.close()
    assert len(scans) == 3
    for k, scan in enumerate(scans):
        np.testing.assert_array_equal(scan.xyz, fake['clouds'][k][:, :3].astype(np.float64))
        np.testing.assert_array_equal(scan.intensity, fake['clouds'][k][:, 3])
        np.testing.assert_array_equal(scan.labels, fake['raws'][k].astype(np.int64))
        np.testing.assert_allclose(scan.pose, lidar_poses[k], atol=1e-9)
        assert scan.stamp_ns == START_NS + round(fake['times'][k] * 1e9)
        assert scan.frame_id == 'velodyne'
    np.testing.assert_allclose(read_kitti_poses(out / 'poses.txt'), lidar_poses, atol=1e-8)
    # The converter refuses to overwrite and a folder reads the same directly.
    assert kitti_to_bag.main([str(tmp_path / 'seq' / '08'), str(out), '--quiet']) == 2
    direct = list(KittiSequence(tmp_path / 'seq' / '08').scans(stride=2))
    assert [s.index for s in direct] == [0, 2]
    np.testing.assert_allclose(direct[1].pose, lidar_poses[2], atol=1e-9)


def test_kitti_converter_without_labels_warns_and_writes_unlabeled(tmp_path: Path) -> None:
    fake = write_fake_kitti(tmp_path / 'seq', np.random.default_rng(3), frames=2, labels=False)
    out = tmp_path / 'bag'
    with pytest.warns(UserWarning, match='no labels/ folder'):
        assert (
            kitti_to_bag.main([str(tmp_path / 'seq'), str(out), '--quiet', '--storage', 'sqlite3'])
            == 0
        )
    scans = list(open_scan_source(out).scans())
    assert len(scans) == 2 and np.all(scans[1].labels == 0)
    np.testing.assert_array_equal(scans[1].xyz, fake['clouds'][1][:, :3].astype(np.float64))


def test_simulate_cli_writes_a_labeled_bag_with_ground_truth(tmp_path: Path) -> None:
    out = tmp_path / 'sim'
    assert (
        simulate.main(
            [
                str(out),
                '--frames',
                '3',
                '--seed',
                '4',
                '--beams',
                '16',
                '--azimuth-steps',
                '256',
                '--storage',
                'sqlite3',
                '--quiet',
            ]
        )
        == 0
    )
    assert (out / 'poses.txt').exists() and (out / 'simulation.yaml').exists()
    source = open_scan_source(out)
    scans = list(source.scans())
    source.close()
    assert len(scans) == 3
    poses = read_kitti_poses(out / 'poses.txt')
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    for k, scan in enumerate(scans):
        np.testing.assert_allclose(scan.pose, poses[k], atol=1e-8)
        learning = LABELS.to_learning(scan.labels, 'raw')
        vehicles = np.isin(learning, [1, 4])
        assert np.all((scan.labels[vehicles] >> 16) > 0)  # instance ids of cars and trucks
        assert np.all((scan.labels[~vehicles] >> 16) == 0)
        assert {9, 11}.issubset(set(np.unique(learning)))  # road and sidewalk
        assert scan.intensity is not None and len(scan) > 1000
    assert 1.9 < np.linalg.norm(poses[2, :3, 3]) < 2.1  # 1 m per frame
    assert simulate.main([str(out), '--frames', '1', '--quiet']) == 2  # exists, no --force


def test_kitti_sequence_to_bag_from_python(tmp_path: Path) -> None:
    """The conversion without the CLI: stride, frame count, summary; a bad sequence leaves none."""
    from mlsemreg_ros.datasets.bag import BagLayout
    from mlsemreg_ros.datasets.kitti_bag import kitti_sequence_to_bag, KittiFiles

    fake = write_fake_kitti(tmp_path / 'seq', np.random.default_rng(4))
    out = tmp_path / 'bag'
    layout = BagLayout('sqlite3', frame_id='lidar')
    conversion = kitti_sequence_to_bag(
        tmp_path / 'seq', out, layout, KittiFiles(start_time_s=10.0), stride=2, progress=False
    )
    assert conversion.written.frames == 2 and conversion.labelled
    assert conversion.summary(out).startswith(f'wrote {out}: 2 scans, ')
    scans = list(open_scan_source(out).scans())
    assert [s.frame_id for s in scans] == ['lidar', 'lidar'] and scans[0].stamp_ns == 10**10
    np.testing.assert_array_equal(scans[1].xyz, fake['clouds'][2][:, :3].astype(np.float64))
    (tmp_path / 'seq' / 'times.txt').write_text('0.0\n')  # 1 time for 3 scans
    with pytest.raises(SourceError, match='times'):
        kitti_sequence_to_bag(tmp_path / 'seq', tmp_path / 'bad', layout, progress=False)
    assert not (tmp_path / 'bad').exists()
