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
``mlsemreg``: the one command line of the package (typer + rich), one subcommand per tool.

Every subcommand is also installed under its old name, ``mlsemreg-<subcommand>``, with the
same flags (the ``main`` of its module). Heavy imports happen inside the commands, so
``mlsemreg --help`` is quick; ``mlsemreg --version`` also checks that they load.
"""

from __future__ import annotations

import importlib
import sys
from typing import Annotated

from mlsemreg_ros.tools import (
    bench,
    bench_labels,
    bench_node,
    chain_pairs,
    confidence,
    covariance,
    cut_pairs,
    demo,
    eval_bag,
    eval_pairs,
    fuzz_node,
    kitti_to_bag,
    label_noise_sweep,
    params,
    play,
    relocalize,
    room_walk,
    self_pairs,
    simulate,
    soak,
    tune,
)
from mlsemreg_ros.tools import map as map_tool
from mlsemreg_ros.tools.common import run, typer_app
import typer

EVALUATION, DATA, MAINTENANCE = 'Evaluation', 'Data and playback', 'Maintenance'
#: (import name, what needs it); the first group must load, the second may be missing.
REQUIRED = (
    'numpy',
    'scipy',
    'open3d',
    'small_gicp',
    'rosbags',
    'threadpoolctl',
    'yaml',
    'matplotlib',
    'tqdm',
)
OPTIONAL = {
    'rclpy': 'the node, play, demo and bench-node (ROS 2 Jazzy)',
    'kiss_icp': 'eval-bag --baseline kiss-icp',
    'kiss_matcher': 'eval-pairs --baseline kiss-matcher',
    'optuna': 'tune',
}

app = typer_app(
    name='mlsemreg',
    no_args_is_help=True,
    help='ML-SemReg registration of labeled LiDAR scans: benchmarks, offline '
    'evaluation, simulation, bags and the ROS 2 node demo.',
)


#: Import name -> distribution name, where they differ.
DISTRIBUTIONS = {
    'small_gicp': 'small-gicp',
    'rclpy': 'ros-jazzy-rclpy',
    'yaml': 'PyYAML',
    'open3d': 'open3d-cpu',
    'kiss_matcher': 'kiss-matcher',
}


def _distribution_version(name: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(DISTRIBUTIONS.get(name, name))
    except metadata.PackageNotFoundError:
        return 'loaded'


def version_report() -> tuple[list[list[str]], bool]:
    """Rows (module, version or error, what needs it) of the heavy imports; all required ok."""
    rows, ok = [], True
    for name in (*REQUIRED, *OPTIONAL):
        try:
            module = importlib.import_module(name)
            version = str(getattr(module, '__version__', '') or _distribution_version(name))
        except Exception as error:  # any import failure is reported, not raised
            version = f'NOT LOADED: {type(error).__name__}: {error}'
            ok = ok and name not in REQUIRED
        rows.append([name, version, OPTIONAL.get(name, 'required')])
    return rows, ok


def _version(value: bool) -> None:
    if not value:
        return
    from mlsemreg_ros import __version__
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable

    rows, ok = version_report()
    print_text(f'mlsemreg_ros {__version__} (Python {sys.version.split()[0]})')
    print_table(ResultTable(('module', 'version', 'needed by'), rows, left_columns=3))
    raise typer.Exit(0 if ok else 1)


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option(
            '--version',
            callback=_version,
            is_eager=True,
            help='show the version and check that the heavy imports load',
        ),
    ] = False,
) -> None:
    """ML-SemReg registration of labeled LiDAR scans."""


for module, function, name, panel in (
    (eval_pairs, eval_pairs.eval_pairs, 'eval-pairs', EVALUATION),
    (eval_bag, eval_bag.eval_bag, 'eval-bag', EVALUATION),
    (bench, bench.bench, 'bench', EVALUATION),
    (bench_node, bench_node.bench_node, 'bench-node', EVALUATION),
    (confidence, confidence.confidence, 'confidence', EVALUATION),
    (label_noise_sweep, label_noise_sweep.label_noise_sweep, 'label-noise-sweep', EVALUATION),
    (demo, demo.demo, 'demo', EVALUATION),
    (soak, soak.soak, 'soak', EVALUATION),
    (fuzz_node, fuzz_node.fuzz_node, 'fuzz-node', EVALUATION),
    (relocalize, relocalize.relocalize, 'relocalize', EVALUATION),
    (covariance, covariance.covariance_nees, 'covariance-nees', EVALUATION),
    (tune, tune.tune, 'tune', EVALUATION),
    (simulate, simulate.simulate, 'simulate', DATA),
    (kitti_to_bag, kitti_to_bag.kitti_to_bag, 'kitti-to-bag', DATA),
    (cut_pairs, cut_pairs.cut_pairs, 'cut-pairs', DATA),
    (chain_pairs, chain_pairs.chain_pairs, 'chain-pairs', DATA),
    (bench_labels, bench_labels.bench_labels, 'bench-labels', EVALUATION),
    (self_pairs, self_pairs.self_pairs, 'self-pairs', EVALUATION),
    (room_walk, room_walk.room_walk, 'room-walk', DATA),
    (play, play.play, 'play', DATA),
    (params, params.params, 'params', MAINTENANCE),
):
    app.command(name, help=module.HELP, rich_help_panel=panel)(function)
app.add_typer(map_tool.app, name='map', help=map_tool.HELP, rich_help_panel=DATA)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg``."""
    args = list(argv) if argv is not None else sys.argv[1:]
    if 'play' in args:
        args = play.expand_topics(args)
    return run(typer.main.get_command(app), args, 'mlsemreg')


if __name__ == '__main__':
    sys.exit(main())
