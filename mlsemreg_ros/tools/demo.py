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
``mlsemreg demo``: the real node on a simulated drive, scored like ``mlsemreg eval-bag``.

1. simulate a drive (default 100 scans, seed 0) into a cache (reused when its parameters
   match): :func:`mlsemreg_ros.simulation.export.cached_simulation`;
2. start ``mlsemreg_node`` (a separate process, reliable subscription, the validated
   ``--config``/``--set`` as its parameter file): :mod:`mlsemreg_ros.ros.node_process`;
3. play the bag's ``/points`` paced by the node's ``/diagnostics`` (one answer per scan,
   so no scan is dropped however slow the machine) and record ``mlsemreg/odometry``,
   ``mlsemreg/transform`` and ``/diagnostics``: :mod:`mlsemreg_ros.ros.recorder`;
4. score the recording with the replay of the evaluation
   (:class:`~mlsemreg_ros.evaluation.estimators.RecordedRunEstimator`), print the table
   and write the results folder (summary, per-frame CSV, trajectories, plots).
"""

from __future__ import annotations

from pathlib import Path
import tempfile
import time
from typing import Annotated, Any

from mlsemreg_ros.codec.stamps import parse_seconds
from mlsemreg_ros.tools.common import (
    alias,
    ConfigOption,
    OUTPUT,
    QuietOption,
    SetOption,
    settings,
)
import typer

HELP = (
    'Simulate a drive (cached), run mlsemreg_node on it through the player, record its '
    'odometry, print the metrics and write plots.'
)

#: Seconds as the node writes them -> exact nanoseconds (kept under its old name).
parse_stamp = parse_seconds


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


def demo(
    frames: Annotated[int, typer.Option(min=2, help='scans of the simulated drive')] = 100,
    seed: Annotated[int, typer.Option(min=0, help='world seed')] = 0,
    cache_dir: Annotated[Path, typer.Option(help='where simulated bags are kept')] = Path(
        '.cache'
    ),
    output: Annotated[
        Path | None,
        typer.Option(
            '-o',
            '--output',
            help='results folder (default: results/demo/<time>_<bag>, link results/demo/latest)',
            rich_help_panel=OUTPUT,
        ),
    ] = None,
    rate: Annotated[
        float, typer.Option(help='player speed factor (playback is also paced by the node)')
    ] = 1.0,
    domain_id: Annotated[
        int,
        typer.Option(
            min=0, max=232, envvar='ROS_DOMAIN_ID', help='ROS_DOMAIN_ID of the node and the player'
        ),
    ] = 0,
    timeout: Annotated[
        float, typer.Option(min=1.0, help='seconds to wait for the node on one scan')
    ] = 120.0,
    config: ConfigOption = None,
    overrides: SetOption = None,
    quiet: QuietOption = False,
) -> int:
    """Run mlsemreg_node on a simulated drive and score it (alias mlsemreg-demo)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.datasets.bag import BagScanReader
    from mlsemreg_ros.evaluation import reports, tables
    from mlsemreg_ros.evaluation.estimators import RecordedRunEstimator
    from mlsemreg_ros.evaluation.replay import replay, ReplayOptions
    from mlsemreg_ros.evaluation.scoring import run_details, summarize_run
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.ros.node_process import start_node, stop_node, write_params_file
    from mlsemreg_ros.ros.recorder import record_and_play, scan_stamps, write_recording
    from mlsemreg_ros.ros.transport import use_fastdds_profile

    # the player (this process) and the node (a child) share config/fastdds.xml
    profile = use_fastdds_profile()

    core, node_settings, evaluation = settings(
        (RegistrationConfig, NodeConfig, EvaluationSettings), config, overrides
    )
    bounds = evaluation.evaluation
    # paced playback needs a reliable subscription with room for a few scans
    node_settings = node_settings.replace({'qos.reliability': 'reliable', 'qos.depth': 10})
    start = time.monotonic()
    bag = ensure_sequence(cache_dir, frames, seed, quiet)
    out = output or reports.default_output(Path('results'), 'demo', bag.name)
    out.mkdir(parents=True, exist_ok=True)
    tables.print_text(
        f'starting mlsemreg_node (ROS_DOMAIN_ID {domain_id}, Fast DDS profile {profile}); '
        f'log: {out / "node.log"}'
    )
    with tempfile.TemporaryDirectory() as folder:
        params = write_params_file(Path(folder) / 'params.yaml', core, node_settings)
        node = start_node(domain_id, params, out / 'node.log')
        try:
            recording = record_and_play(bag, domain_id, rate, timeout, node, quiet)
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
        node_params=list(overrides or []),
        total_time_s=time.monotonic() - start,
    )
    reports.write_results(out, run_, summary, details, None, bounds)
    if output is None:
        reports.link_latest(out)
    tables.print_table(tables.sequence_summary_table(summary, run_.method))
    tables.print_text(f'results: {out}  ({time.monotonic() - start:.0f} s in total)')
    return 0 if len(recording.diagnostics) == len(run_.records) else 1


main = alias(demo, HELP, 'mlsemreg-demo')
