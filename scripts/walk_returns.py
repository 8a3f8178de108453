#!/usr/bin/env python3
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
Count the walk of one scan through ``Odometry.process``: modules, visits and returns.

Replays the first frames of a bag (or SemanticKITTI folder) through the odometry and traces
the calls of the chosen frame: the sequence of the package's modules the scan's code is in
(calls into NumPy, small_gicp and the like stay in the caller's module), with consecutive
repeats merged. A *visit* is one stay in a module; a *return* is a visit to a module the
walk had already left (visits minus modules). Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/walk_returns.py BAG [--frame 20] [--scope odometry]

``--depth 2`` follows ``process`` one module down (its rooms: what it calls, and back).
``--scope odometry`` counts only the odometry's and the alignment's modules
(``core/odometry``, ``core/alignment``: the rooms of docs/architecture.md's odometry),
``--scope core`` every module of ``core``. ``--show`` prints the walk.
"""

from __future__ import annotations

import argparse
import sys

SCOPES = {
    'odometry': ('mlsemreg_ros.core.odometry', 'mlsemreg_ros.core.alignment'),
    'core': ('mlsemreg_ros.core',),
}


def _at_depth(stack: list[str], depth: int) -> str:
    """The module of ``stack`` at ``depth`` module changes from the bottom (or the top one)."""
    level, module = 0, ''
    for here in stack:
        if here != module:
            level, module = level + 1, here
            if level == depth:
                return module
    return module


def trace_walk(odometry, scan, prefixes: tuple[str, ...], depth: int = 0) -> list[str]:
    """
    Return the modules ``odometry.process(scan)`` passes through, repeats merged.

    ``depth`` > 0: a call deeper than ``depth`` modules below ``process`` stays in its
    ancestor at that depth (``--depth 2``: the walk of ``process`` through its rooms).
    """
    stack: list[str] = []
    walk: list[str] = []

    def profile(frame, event, arg):
        if event not in ('call', 'return'):
            return
        module = frame.f_globals.get('__name__', '')
        if not module.startswith(prefixes):
            return
        if event == 'call':
            stack.append(module)
        elif stack:
            stack.pop()
        here = (_at_depth(stack, depth) if depth else stack[-1]) if stack else None
        if here is not None and (not walk or walk[-1] != here):
            walk.append(here)

    sys.setprofile(profile)
    try:
        odometry.process(scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times)
    finally:
        sys.setprofile(None)
    return walk


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag', help='rosbag2 directory or SemanticKITTI sequence folder')
    parser.add_argument('--frame', type=int, default=20, help='the traced frame (default 20)')
    parser.add_argument('--scope', choices=sorted(SCOPES), default='odometry')
    parser.add_argument('--set', action='append', default=[], help='section.key=value')
    parser.add_argument(
        '--depth', type=int, default=0, help='follow calls this many modules deep (0: all)'
    )
    parser.add_argument('--show', action='store_true', help='print the walk')
    args = parser.parse_args()

    from mlsemreg_ros.core.config import parse_overrides, RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.datasets.factory import open_scan_source

    config = RegistrationConfig().replace(parse_overrides(args.set))
    odometry = Odometry(config=config)
    source = open_scan_source(args.bag)
    for scan in source.scans(max_frames=args.frame + 1):
        if scan.index < args.frame:
            odometry.process(scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times)
            continue
        walk = trace_walk(odometry, scan, SCOPES[args.scope], args.depth)
    source.close()
    modules = sorted(set(walk))
    if args.show:
        print(' -> '.join(m.rsplit('.', 1)[-1] for m in walk))
    print(
        f'frame {args.frame}: {len(modules)} modules, {len(walk)} visits, '
        f'{len(walk) - len(modules)} returns ({args.scope}, depth {args.depth or "all"})'
    )
    for module in modules:
        print(f'  {walk.count(module):3d}  {module}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
