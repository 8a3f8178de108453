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
A simulated drive as a rosbag2 (``mlsemreg simulate``), and a cache of such bags (the demo).

The bag: ``/points`` PointCloud2 with x, y, z, intensity and a uint32 SemanticKITTI raw
label, ``/ground_truth/odometry``; next to the storage file ``poses.txt`` (KITTI format,
LiDAR frame, frame 0 = identity), ``times.txt`` and ``simulation.yaml`` (the parameters,
to reproduce the bag).
"""

from __future__ import annotations

from collections.abc import Iterator
import dataclasses
from dataclasses import dataclass
from pathlib import Path
import shutil
import time

from mlsemreg_ros.datasets.bag import BagLayout, write_sequence_bag
from mlsemreg_ros.datasets.source import Scan
from mlsemreg_ros.simulation.sequence import Simulation, SimulationConfig
import numpy as np
import yaml


@dataclass
class SimulationReport:
    """What :func:`write_simulation_bag` wrote, and how long it took."""

    frames: int
    points_per_scan: float
    path_m: float  # length of the driven path
    world_s: float  # building the world
    total_s: float

    def summary(self, out: Path) -> str:
        """Return the one line ``mlsemreg simulate`` prints."""
        return (
            f'wrote {out}: {self.frames} scans, {self.points_per_scan:.0f} points/scan, '
            f'{self.path_m:.1f} m driven; world {self.world_s:.1f} s, total '
            f'{self.total_s:.1f} s'
        )


def _scans(sim: Simulation, progress: bool) -> Iterator[Scan]:
    from tqdm import tqdm

    for frame in tqdm(sim, total=len(sim), desc='simulate', unit='scan', disable=not progress):
        scan = frame.scan
        yield Scan(
            frame.index,
            frame.stamp_ns,
            scan.points,
            sim.raw_labels(scan),
            scan.intensity,
            '',
            frame.pose,
        )


def write_simulation_bag(
    out: Path, config: SimulationConfig, layout: BagLayout | None = None, progress: bool = True
) -> SimulationReport:
    """Simulate ``config`` and write the bag folder ``out`` (which must not exist)."""
    layout = layout or BagLayout()
    start = time.perf_counter()
    sim = Simulation(config)
    built = time.perf_counter()
    written = write_sequence_bag(out, _scans(sim, progress), layout)
    meta = {
        'simulation': dataclasses.asdict(config),
        'topics': {'points': layout.points_topic, 'ground_truth': layout.gt_topic},
        'frames': {'sensor': layout.frame_id, 'world': layout.world_frame},
        'world': {
            'triangles': sim.world.num_triangles,
            'blocks': {f'{i},{j}': kind for (i, j), kind in sim.world.blocks.items()},
            'objects': sim.world.object_counts,
        },
    }
    (out / 'simulation.yaml').write_text(yaml.safe_dump(meta, sort_keys=False))
    path_m = float(np.sum(np.linalg.norm(np.diff(sim.poses[:, :3, 3], axis=0), axis=1)))
    return SimulationReport(
        written.frames, written.points_per_scan, path_m, built - start, time.perf_counter() - start
    )


def cached_simulation(
    cache_dir: Path, config: SimulationConfig, progress: bool = True
) -> tuple[Path, bool]:
    """
    Return ``(bag, reused)``: the cached bag of ``config``, simulated first if needed.

    The bag is ``cache_dir/sim_seed<seed>_<frames>f``; it is reused only when its
    ``simulation.yaml`` holds exactly ``config``.
    """
    bag = cache_dir / f'sim_seed{config.seed}_{config.frames}f'
    wanted = yaml.safe_dump(yaml.safe_load(yaml.safe_dump(dataclasses.asdict(config))))
    meta = bag / 'simulation.yaml'
    if meta.exists() and (bag / 'metadata.yaml').exists():
        saved = yaml.safe_load(meta.read_text()).get('simulation', {})
        if yaml.safe_dump(saved) == wanted:
            return bag, True
    if bag.exists():
        shutil.rmtree(bag)
    bag.parent.mkdir(parents=True, exist_ok=True)
    write_simulation_bag(bag, config, progress=progress)
    return bag, False
