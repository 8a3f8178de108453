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
"""``sweep_alignment.screen_points``: a partial view's quick look before the sweep alignment."""

from mlsemreg_ros.core.alignment.alignment import AlignmentCloud
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.deskew import deskew, SweepMotion
from mlsemreg_ros.core.odometry.local_map import make_map
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
from mlsemreg_ros.core.odometry.sweep_screen import screened
from mlsemreg_ros.core.odometry.tracking import Tracker
import numpy as np
import pytest

STILL = SweepMotion(np.zeros(3), np.zeros(3))


class _Preprocessor:
    """The preprocessor's one method the look reads (no moving objects)."""

    @staticmethod
    def moving_mask(points: np.ndarray, labels: object) -> None:
        return None


def _scene(rng: np.random.Generator) -> np.ndarray:
    """Return a ground and three walls (0.1 m apart) within 40 m of the origin."""
    ground = np.column_stack([rng.uniform(0, 40, (6000, 2)) - [0, 20], np.full(6000, -1.5)])
    walls = []
    for x in (15.0, 28.0, 38.0):
        yz = np.column_stack([rng.uniform(-20, 20, 3000), rng.uniform(-1.5, 4.0, 3000)])
        walls.append(np.column_stack([np.full(3000, x), yz]))
    side = np.column_stack(
        [rng.uniform(5, 40, 3000), np.full(3000, 12.0), rng.uniform(-1.5, 4.0, 3000)]
    )
    return np.vstack([ground, *walls, side])


def _setup(config: RegistrationConfig, span_deg: float) -> tuple[Tracker, np.ndarray]:
    """Return a tracker whose map holds the scene, and the scene's 70 deg view."""
    rng = np.random.default_rng(3)
    scene = _scene(rng)
    local_map = make_map(config)
    local_map.insert(AlignmentCloud.build(scene, config.fine.downsampling_resolution), np.eye(4))
    tracker = Tracker(local_map)
    tracker.trust.view.span_deg = span_deg
    azimuth = np.degrees(np.arctan2(scene[:, 1], scene[:, 0]))
    view = scene[(np.abs(azimuth) <= 35.0) & (np.linalg.norm(scene[:, :2], axis=1) > 2.0)]
    return tracker, view


def _scan(points: np.ndarray, omega_z: float, known: bool = False) -> PreprocessedScan:
    """
    Return the view taken over 0.1 s while the sensor turned at ``omega_z`` rad/s.

    Deskewed as if still, or (``known``) by that turn.
    """
    times = np.linspace(0.0, 0.1, len(points))
    turning = SweepMotion(np.array([0.0, 0.0, omega_z]), np.zeros(3))
    raw = deskew(points, times, SweepMotion(-turning.omega, np.zeros(3)))  # as the sensor saw
    assert np.allclose(deskew(raw, times, turning), points, atol=1e-6)
    motion = turning if known else STILL
    return PreprocessedScan(raw, np.zeros(len(raw)), None, True, times, '', raw, motion=motion)


def test_a_partial_views_tracked_scan_without_a_bend_skips_the_full_alignment() -> None:
    config = RegistrationConfig()
    assert config.sweep_alignment.screen_points == 500
    tracker, view = _setup(config, 70.0)
    still = _scan(view, 0.0)
    looked = screened(tracker, True, still, np.eye(4), _Preprocessor(), config, None)
    assert looked is not None and looked <= config.sweep_alignment.min_change
    # any other decision, a full ring, or the look turned off: the full alignment
    assert screened(tracker, False, still, np.eye(4), _Preprocessor(), config, None) is None
    full_ring, _ = _setup(config, 360.0)
    assert screened(full_ring, True, still, np.eye(4), _Preprocessor(), config, None) is None
    off = config.replace({'sweep_alignment.screen_points': 0})
    assert screened(tracker, True, still, np.eye(4), _Preprocessor(), off, None) is None


@pytest.mark.parametrize('rate_deg', [-60.0, 60.0])
def test_a_turn_the_deskew_missed_gets_the_full_alignment(rate_deg: float) -> None:
    """A 70 deg view swept while turning at 60 deg/s, deskewed as if still: bent by metres."""
    config = RegistrationConfig()
    tracker, view = _setup(config, 70.0)
    bent = _scan(view, np.radians(rate_deg))
    assert screened(tracker, True, bent, np.eye(4), _Preprocessor(), config, None) is None


def test_a_scan_deskewed_in_a_turn_gets_the_full_alignment() -> None:
    """Deskewed by the turn it was taken in (no bend), but the rate may change: in full."""
    config = RegistrationConfig()
    tracker, view = _setup(config, 70.0)
    known = _scan(view, np.radians(40.0), known=True)
    assert screened(tracker, True, known, np.eye(4), _Preprocessor(), config, None) is None
    slow = _scan(view, np.radians(5.0), known=True)  # a straight drive's rate noise
    assert screened(tracker, True, slow, np.eye(4), _Preprocessor(), config, None) is not None
