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
A second field-mode drive through the world of a field-mode drive, for relocalization queries.

The field counterpart of :func:`mlsemreg_ros.simulation.revisit.reverse_drive`
(docs/maps.md): the streets of the first drive (:class:`FieldSimulation`, the bag that
``mlsemreg simulate --realism field`` writes) driven backwards, in the other lane
(``lane_change`` metres to the first drive's left), ``start_offset`` metres later, as a
continuous drive of the same motion profile. Its sweeps are skewed like the first drive's
(the sensor moves while it turns, :mod:`.field_lidar`), see the same world with its
parked cars and moving actors at the query's time, and carry the same simulated network's
labels (its errors are anchored in the world, so both drives share them, as a real
network's would; the per-sweep flicker is drawn for sweep numbers that the first drive
does not use).

A query is written at the sweep's start (its header stamp), its points motion-compensated
to that instant (``core/features/deskew.py``) as ``deskew`` says: ``odometry``, by the
odometry itself (:mod:`.field_odometry_queries`: every sweep goes through it, as in the
node, which relocalizes the scan the odometry deskewed); ``previous``, the twist over the
previous sweep period (what a constant-velocity prediction gives; wrong where the turn rate
changes within a period); ``sweep``, the true twist over the sweep itself (what an
IMU-aided deskew comes close to); ``off``, the raw skewed sweep.
:func:`field_reverse_sweeps` and :func:`field_other_sweeps` give the sweeps as a bag holds
them (float32 points and times, raw labels), for the odometry.

:func:`field_other_drive` gives the loop route of the same seed instead (``mlsemreg
simulate --realism field --route loop``): the same city, mostly other streets; the
queries kept are those far from the first drive, which a map of it has not seen.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

from mlsemreg_ros.core.features.deskew import deskew as deskew_points
from mlsemreg_ros.core.features.deskew import sweep_motion
from mlsemreg_ros.simulation.field import FieldConfig, FieldFrame, FieldSimulation
from mlsemreg_ros.simulation.field_lidar import FieldScan
from mlsemreg_ros.simulation.motion import ContinuousDrive
from mlsemreg_ros.simulation.revisit import clip_path, clip_path_from, QueryScan, reversed_path
import numpy as np

#: Sweep numbers of the second drive's label flicker start here (the first drive's are 0..F-1).
FLICKER_OFFSET = 1_000_000


def field_reverse_drive(
    config: FieldConfig,
    lane_change: float = 3.6,
    start_offset: float = 0.5,
    noise_seed: int = 1000,
) -> tuple[FieldSimulation, ContinuousDrive, np.ndarray]:
    """Return the first drive, the drive back along its streets, and its sweep starts (s)."""
    sim = FieldSimulation(config)
    period = sim.model.period
    driven = float(sim.drive.arc_length(np.array([sim.sweep_starts[-1] + period]))[0])
    path = clip_path_from(reversed_path(clip_path(sim.path, driven), lane_change), start_offset)
    traj = sim.profile.trajectory_config(config.trajectory)
    speed = config.speed if config.speed is not None else sim.profile.cruise_speed
    phases = np.random.default_rng([noise_seed, 4]).uniform(0.0, 2.0 * np.pi, size=4)
    drive = ContinuousDrive(path, speed, traj, sim.model.mount_height, phases)
    starts = np.arange(config.lead_in, drive.duration - 2.0 * period, period)
    return sim, drive, starts


def field_other_drive(config: FieldConfig) -> tuple[FieldSimulation, FieldSimulation]:
    """Return the first drive and the loop route of its seed (the same city, other streets)."""
    return FieldSimulation(config), FieldSimulation(replace(config, route='loop', frames=0))


#: How a query sweep is motion-compensated: by the odometry (as in the node), by the true
#: twist over the previous period (as a constant-velocity prediction) or over the sweep
#: itself (as an IMU-aided deskew), or not at all.
DESKEW_MODES = ('odometry', 'previous', 'sweep', 'off')


@dataclass
class TimedSweep:
    """A sweep as a bag holds it (what the node's odometry gets), with its ground truth."""

    index: int
    stamp_ns: int  # header stamp = sweep start
    points: np.ndarray  # (N, 3) float64 of float32 values, sensor frame at each point's time
    times: np.ndarray  # (N,) float64 of float32 values, s after the stamp
    labels: np.ndarray  # (N,) int64 raw labels of the network (moving ids, instance bits)
    T_map_scan: np.ndarray  # (4, 4) at the stamp, in the first drive's map frame


def _timed(sim: FieldSimulation, frame: FieldFrame, T_map_scan: np.ndarray) -> TimedSweep:
    """Return ``frame`` as the bag of ``mlsemreg simulate`` would give it to the odometry."""
    labels, _ = sim.raw_labels(frame)
    return TimedSweep(
        frame.index,
        frame.stamp_ns,
        frame.scan.points.astype(np.float32).astype(np.float64),
        frame.scan.times.astype(np.float32).astype(np.float64),
        labels.astype(np.int64),
        T_map_scan,
    )


def field_reverse_sweeps(
    sim: FieldSimulation, drive: ContinuousDrive, starts: np.ndarray, count: int, noise_seed: int
) -> Iterator[TimedSweep]:
    """Render the first ``count`` sweeps of ``drive`` in order, poses in ``sim``'s map frame."""
    origin_inv = np.linalg.inv(sim.world_poses[0])
    first_drive = sim.drive
    try:
        sim.drive = drive  # the actors are placed around the drive that is rendered
        for index in range(min(count, len(starts))):
            t0 = float(starts[index])
            scan, labels = _render(sim, drive, t0, index, noise_seed)
            pose = origin_inv @ drive.poses(np.array([t0]))[0]
            frame = FieldFrame(index, int(sim.stamp_ns(t0)), pose, scan, labels)
            yield _timed(sim, frame, pose)
    finally:
        sim.drive = first_drive


def field_other_sweeps(
    sim: FieldSimulation, other: FieldSimulation, count: int
) -> Iterator[TimedSweep]:
    """Render the first ``count`` sweeps of the ``other`` drive, poses in ``sim``'s map frame."""
    origin_inv = np.linalg.inv(sim.world_poses[0])
    for index in range(min(count, len(other))):
        yield _timed(other, other.frame(index), origin_inv @ other.world_poses[index])


def _render(
    sim: FieldSimulation, drive: ContinuousDrive, t0: float, index: int, noise_seed: int
) -> tuple[FieldScan, np.ndarray]:
    """Render sweep ``index`` of ``drive`` at ``t0`` in ``sim``'s world: the scan, its labels."""
    dynamic = sim.actors.dynamic_mesh(t0, sim) if sim.actors is not None else None
    rng = np.random.default_rng([noise_seed, 5, int(index)])
    scan = sim.lidar.sweep(drive, t0, rng, dynamic)
    labels = scan.labels
    if sim.label_model is not None:
        labels = sim.label_model.predict(scan, FLICKER_OFFSET + int(index))
    return scan, labels


def _deskewed(
    scan: FieldScan, drive: ContinuousDrive, t0: float, period: float, mode: str
) -> np.ndarray:
    """Return the sweep's points at its start, deskewed by the truth (``previous|sweep|off``)."""
    points = scan.points.astype(np.float64)
    if mode == 'off':
        return points
    span = (t0 - period, t0) if mode == 'previous' else (t0, t0 + period)
    a, b = drive.poses(np.array(span))
    motion = sweep_motion(a, 1, b, 1 + round(period * 1e9))
    return points if motion is None else deskew_points(points, scan.times, motion)


def render_field_queries(
    sim: FieldSimulation,
    drive: ContinuousDrive,
    starts: np.ndarray,
    indices: np.ndarray,
    noise_seed: int,
    deskew: str,
) -> Iterator[QueryScan]:
    """Render the sweeps ``indices`` of ``drive`` in ``sim``'s world, poses in its map frame."""
    period = sim.model.period
    origin_inv = np.linalg.inv(sim.world_poses[0])
    first_drive = sim.drive
    try:
        sim.drive = drive  # the actors are placed around the drive that is rendered
        for index in np.asarray(indices, dtype=np.int64):
            t0 = float(starts[index])
            scan, labels = _render(sim, drive, t0, int(index), noise_seed)
            points = _deskewed(scan, drive, t0, period, deskew)
            pose = origin_inv @ drive.poses(np.array([t0]))[0]
            yield QueryScan(int(index), points.astype(np.float32), labels.astype(np.int32), pose)
    finally:
        sim.drive = first_drive


def render_other_queries(
    sim: FieldSimulation, other: FieldSimulation, indices: np.ndarray, deskew: str
) -> Iterator[QueryScan]:
    """Render sweeps ``indices`` of the ``other`` drive, poses in ``sim``'s map frame."""
    origin_inv = np.linalg.inv(sim.world_poses[0])
    period = other.model.period
    for index in np.asarray(indices, dtype=np.int64):
        frame = other.frame(int(index))
        t0 = float(other.sweep_starts[index])
        points = _deskewed(frame.scan, other.drive, t0, period, deskew)
        pose = origin_inv @ other.world_poses[index]
        yield QueryScan(int(index), points.astype(np.float32), frame.labels.astype(np.int32), pose)
