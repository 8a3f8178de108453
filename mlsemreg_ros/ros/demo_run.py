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
The demo's run: the real node on a simulated drive, scored like ``mlsemreg eval-bag``.

:func:`run_demo` (``mlsemreg demo``, docs/tools.md):

1. simulate a drive (default 100 scans, seed 0) into a cache (reused when its parameters
   match): :func:`ensure_sequence`, :func:`mlsemreg_ros.simulation.export.cached_simulation`;
2. start ``mlsemreg_node`` (a separate process, reliable subscription, the validated
   settings as its parameter file): :mod:`mlsemreg_ros.ros.node_process`;
3. play the bag's ``/points`` paced by the node's ``/diagnostics`` (one answer per scan,
   so no scan is dropped however slow the machine) and record ``mlsemreg/odometry``,
   ``mlsemreg/transform`` and ``/diagnostics``: :mod:`mlsemreg_ros.ros.recorder`;
4. score the recording with the replay of the evaluation
   (:class:`~mlsemreg_ros.evaluation.estimators.RecordedRunEstimator`) and write the
   results folder (summary, per-frame CSV, trajectories, plots).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import tempfile
import time
from typing import Any


@dataclass(frozen=True)
class DemoOptions:
    """The simulated drive, where the results go, and how the node is played to."""

    frames: int = 100  # scans of the simulated drive
    seed: int = 0  # world seed
    cache_dir: Path = Path('.cache')  # where simulated bags are kept
    output: Path | None = None  # results folder (None: results/demo/<time>_<bag>, latest)
    rate: float = 1.0  # player speed factor (playback is also paced by the node)
    domain_id: int = 0  # ROS_DOMAIN_ID of the node and the player
    timeout: float = 120.0  # seconds to wait for the node on one scan
    quiet: bool = False  # no progress bars


@dataclass
class DemoResult:
    """Where the results went, the scores, and whether the node answered every scan."""

    out: Path
    summary: dict[str, Any]
    method: str
    answered_scans: int
    scans: int
    seconds: float

    @property
    def complete(self) -> bool:
        """Return whether the node answered every scan of the drive."""
        return self.answered_scans == self.scans


def ensure_sequence(cache_dir: Path, frames: int, seed: int, quiet: bool) -> Path:
    """Return the cached simulated bag for (frames, seed), simulating it if needed."""
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.simulation.export import cached_simulation
    from mlsemreg_ros.simulation.sequence import SimulationConfig

    config = SimulationConfig(seed=seed, frames=frames)
    bag = cache_dir / f'sim_seed{seed}_{frames}f'
    if not (bag / 'simulation.yaml').exists():
        print_text(f'simulating {frames} scans (seed {seed}) into {bag} ...')
    bag, reused = cached_simulation(cache_dir, config, progress=not quiet)
    print_text(f'using the cached sequence {bag}' if reused else f'simulated {bag}')
    return bag


def correspondence_pair(bag: Path, run: Any, core: Any, bounds: Any) -> dict | None:
    """Register the middle pair offline (same core and parameters) for correspondences.png."""
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.core.rigid import relative_transform
    from mlsemreg_ros.datasets.bag import BagScanReader
    from mlsemreg_ros.evaluation.records import FrameEstimate, PairClouds
    from mlsemreg_ros.evaluation.replay import correspondence_plot_data

    pairs = [r for r in run.records if r.registered]
    if not pairs:
        return None
    record = pairs[len(pairs) // 2]
    source = BagScanReader(bag)
    try:
        scans = {
            s.index: s
            for s in source.scans()
            if s.index in (record.bag_index, record.keyframe_index)
        }
    finally:
        source.close()
    current, keyframe = scans[record.bag_index], scans[record.keyframe_index]
    if current.pose is None or keyframe.pose is None:
        return None
    registration = Registration(core)
    target = registration.prepare(keyframe.xyz, keyframe.labels)
    prepared = registration.prepare(current.xyz, current.labels)
    result = registration.register(prepared, target)
    estimate = FrameEstimate(
        current.pose,
        keyframe.index,
        source_points=result.source_points,
        target_points=result.target_points,
        clouds=PairClouds(target.points, target.labels, prepared.points, prepared.labels),
    )
    return correspondence_plot_data(
        estimate,
        relative_transform(keyframe.pose, current.pose),
        record.bag_index,
        record.keyframe_index,
        bounds,
    )


def run_demo(
    options: DemoOptions, core: Any, node_settings: Any, bounds: Any, overrides: list[str]
) -> DemoResult:
    """Run ``mlsemreg_node`` on the simulated drive, record it, score it, write the results."""
    from mlsemreg_ros.datasets.bag import BagScanReader
    from mlsemreg_ros.evaluation import reports, tables
    from mlsemreg_ros.evaluation.estimators import RecordedRunEstimator
    from mlsemreg_ros.evaluation.replay import replay, ReplayOptions
    from mlsemreg_ros.evaluation.scoring import run_details, summarize_run
    from mlsemreg_ros.ros.node_process import start_node, stop_node, write_params_file
    from mlsemreg_ros.ros.recorder import record_and_play, scan_stamps, write_recording
    from mlsemreg_ros.ros.transport import use_fastdds_profile

    # the player (this process) and the node (a child) share config/fastdds.xml
    profile = use_fastdds_profile()
    # paced playback needs a reliable subscription with room for a few scans
    node_settings = node_settings.replace({'qos.reliability': 'reliable', 'qos.depth': 10})
    start = time.monotonic()
    bag = ensure_sequence(options.cache_dir, options.frames, options.seed, options.quiet)
    out = options.output or reports.default_output(Path('results'), 'demo', bag.name)
    out.mkdir(parents=True, exist_ok=True)
    tables.print_text(
        f'starting mlsemreg_node (ROS_DOMAIN_ID {options.domain_id}, Fast DDS profile '
        f'{profile}); log: {out / "node.log"}'
    )
    with tempfile.TemporaryDirectory() as folder:
        params = write_params_file(Path(folder) / 'params.yaml', core, node_settings)
        node = start_node(options.domain_id, params, out / 'node.log')
        try:
            recording = record_and_play(
                bag, options.domain_id, options.rate, options.timeout, node, options.quiet
            )
        finally:
            stop_node(node)
    write_recording(out / 'recorded_odometry', recording)
    source = BagScanReader(bag)
    try:
        estimator = RecordedRunEstimator(recording, scan_stamps(bag).tolist())
        run_ = replay(source, estimator, bounds, ReplayOptions(progress=False))
    finally:
        source.close()
    run_.plot_pair = correspondence_pair(bag, run_, core, bounds)
    summary = summarize_run(run_)
    details = run_details(
        run_,
        bag=str(bag),
        answered_scans=len(recording.diagnostics),
        node_params=list(overrides),
        total_time_s=time.monotonic() - start,
    )
    reports.write_results(out, run_, summary, details, None, bounds)
    if options.output is None:
        reports.link_latest(out)
    answered, seconds = len(recording.diagnostics), time.monotonic() - start
    return DemoResult(out, summary, run_.method, answered, len(run_.records), seconds)
