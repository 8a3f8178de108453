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
The odometry peers of ``eval-bag --baseline``, each replayed on the same scans as ours.

``kiss-icp`` (KISS-ICP 1.3.0), ``genz-icp`` (GenZ-ICP 0.3.2) and ``kiss-slam`` (KISS-SLAM
0.0.2) are regular requirements; a peer whose package is missing is named with the command
that installs it (:class:`PeerUnavailable`) before anything runs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
import importlib.util
from pathlib import Path
from typing import Any, TYPE_CHECKING

if TYPE_CHECKING:  # the command line imports this module for OdometryPeer: keep it light
    from mlsemreg_ros.evaluation.replay import ReplayOptions
    from mlsemreg_ros.evaluation.settings import EvaluationConfig
    import numpy as np

#: ``--baseline`` name -> (import name, how to install it).
PEER_PACKAGES = {
    'kiss-icp': ('kiss_icp', "pip install 'kiss-icp==1.3.0'"),
    'genz-icp': ('genz_icp', "pip install 'genz-icp==0.3.2'"),
    'kiss-slam': ('kiss_slam', 'pip install --no-deps -r requirements-nodeps.txt'),
    'map-closures': ('map_closures', 'pip install --no-deps -r requirements-nodeps.txt'),
}


class OdometryPeer(StrEnum):
    """The odometry peers of ``eval-bag --baseline``."""

    kiss_icp = 'kiss-icp'
    genz_icp = 'genz-icp'
    kiss_slam = 'kiss-slam'


ODOMETRY_PEERS = tuple(peer.value for peer in OdometryPeer)


class LoopPeer(StrEnum):
    """The loop-closure peers of ``map build --baseline`` (evaluation/loop_peers.py)."""

    kiss_slam = 'kiss-slam'
    map_closures = 'map-closures'


class PlacePeer(StrEnum):
    """The place-recognition peers of ``relocalize --baseline`` (evaluation/loop_peers.py)."""

    map_closures = 'map-closures'


#: What each peer imports besides its own package (KISS-SLAM's loop closer is MapClosures).
PEER_NEEDS = {'kiss-slam': ('map-closures',)}


class PeerUnavailable(RuntimeError):
    """A peer's package is not installed."""


def missing_peers(names: list[str]) -> list[str]:
    """Return ``'name (install line)'`` of each named peer whose package is missing."""
    wanted = [str(name) for name in names]
    wanted += [need for name in wanted for need in PEER_NEEDS.get(name, ())]
    return [
        f'{name} ({PEER_PACKAGES[name][1]})'
        for name in dict.fromkeys(wanted)
        if importlib.util.find_spec(PEER_PACKAGES[name][0]) is None
    ]


def require_peers(names: list[str]) -> None:
    """Raise :class:`PeerUnavailable` naming every missing peer and how to install it."""
    missing = missing_peers(names)
    if missing:
        raise PeerUnavailable('peer not installed: ' + '; '.join(missing))


def odometry_estimator(name: str) -> Any:
    """Return a fresh estimator of the peer ``name`` (one of :data:`ODOMETRY_PEERS`)."""
    from mlsemreg_ros.evaluation.estimators import KissIcpEstimator
    from mlsemreg_ros.evaluation.peer_estimators import GenZIcpEstimator, KissSlamEstimator

    require_peers([name])
    classes = {
        'kiss-icp': KissIcpEstimator,
        'genz-icp': GenZIcpEstimator,
        'kiss-slam': KissSlamEstimator,
    }
    return classes[name]()


@dataclass
class PeerResults:
    """What the peers gave, by method label (``KISS-ICP``, ``GenZ-ICP``, ...)."""

    summaries: dict[str, dict[str, Any]] = field(default_factory=dict)
    details: dict[str, dict[str, Any]] = field(default_factory=dict)
    deskewed_scans: dict[str, int] = field(default_factory=dict)
    poses: dict[str, np.ndarray] = field(default_factory=dict)  # (F, 4, 4) for the plots


def run_odometry_peers(
    open_source: Callable[[], Any],
    names: list[str],
    bounds: EvaluationConfig,
    options: ReplayOptions,
    out: Path,
    **run_info: Any,
) -> PeerResults:
    """
    Replay each named peer on a fresh source and write its results to ``out/<name>/``.

    - ``open_source``: returns a new scan source (closed here after the replay).
    - ``options``: the same scans (stride, frame count, ground truth) as our run.
    - ``run_info``: more entries of each peer's details.json (bag, stride).
    """
    from mlsemreg_ros.evaluation import reports
    from mlsemreg_ros.evaluation.replay import replay
    from mlsemreg_ros.evaluation.scoring import run_details, summarize_run

    require_peers(names)
    results = PeerResults()
    for name in dict.fromkeys(map(str, names)):
        estimator = odometry_estimator(name)
        source = open_source()
        try:
            run = replay(source, estimator, bounds, options)
        finally:
            source.close()
        summary = summarize_run(run)
        details = run_details(run, deskewed_scans=estimator.deskewed_scans, **run_info)
        if hasattr(estimator, 'closures'):
            details['loop_closures'] = len(estimator.closures)
        results.summaries[run.method] = summary
        results.details[run.method] = details
        results.deskewed_scans[run.method] = estimator.deskewed_scans
        results.poses[run.method] = run.poses
        reports.write_results(out / name, run, summary, details, None, bounds, plots=False)
    return results
