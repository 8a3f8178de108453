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
The seeded search after a lost scan (issue 29, core/odometry/seeded_search.py).

Known answers on hand-made evidence (a rival place or a slide too close refuses the best
place; a denser rival refuses it) and the real dev chain with scan 5 lost in place: scan 6,
40 m from the map, registers right, and the chain goes on (10 right, 0 wrong); with the
search off it is refused (5 right, the chain stalls).
"""

from __future__ import annotations

from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import seeded_search
from mlsemreg_ros.core.odometry.seeded_search import Place
from mlsemreg_ros.core.rigid import rotation_angle_deg
from mlsemreg_ros.core.settings import parse_overrides
import numpy as np
import pytest


def _moved(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3] = x
    return T


def _place(x: float, overlap: float, dense: float, checked: float = 0.23) -> Place:
    return Place(SimpleNamespace(), 50, _moved(x), dense, overlap, checked)


def test_the_seeds_turn_and_move_the_prediction_along_its_heading() -> None:
    """15 seeds: the prediction itself among them, each along its heading and turned."""
    predicted = _moved(10.0, 90.0)
    found = seeded_search.seeds(predicted)
    assert len(found) == len(seeded_search.SEED_YAWS_DEG) * len(seeded_search.SEED_ALONG_M)
    assert any(np.allclose(T, predicted) for T in found)
    ahead = [T for T in found if np.isclose(rotation_angle_deg(np.linalg.solve(predicted, T)), 0)]
    assert sorted(np.round(T[1, 3], 6) for T in ahead) == [-4.0, 0.0, 4.0]  # heading: +y


def test_the_seeds_cluster_and_the_rivals(monkeypatch) -> None:
    """Places within confidence.rival_* of the best one are one place; the rest are rivals."""
    cfg = RegistrationConfig()
    places = [_place(0.0, 0.99, 0.15), _place(0.4, 1.0, 0.16), _place(5.0, 0.9, 0.14)]
    cluster, rivals = seeded_search._cluster(places, cfg)
    assert cluster[0] is places[1] and any(p is places[0] for p in cluster)
    assert len(rivals) == 1 and rivals[0] is places[2]


@pytest.mark.parametrize(
    ('rival', 'slide', 'refused'),
    [
        ((0.93, 0.14), 0.80, ''),  # the dev chain's margins: accepted
        ((0.98, 0.14), 0.80, 'a distinct candidate'),  # a rival within accept_gap
        ((0.93, 0.14), 0.99, 'a slide'),  # a straight street: the slide fits as well
        ((0.93, 0.17), 0.80, 'dense scans'),  # a rival with the better dense score
    ],
)
def test_a_place_needs_its_margin_over_every_rival_and_slide(
    monkeypatch, rival: tuple[float, float], slide: float, refused: str
) -> None:
    """The best place is refused when a rival place or a slide reaches its evidence."""
    cfg = RegistrationConfig()
    monkeypatch.setattr(
        seeded_search,
        '_covisible',
        lambda transforms, *_: (np.full(len(transforms), slide), np.full(len(transforms), 0.2)),
    )
    best = _place(0.0, 1.0, 0.164)
    refusal = seeded_search._place_refusal(best, [_place(6.0, *rival)], None, None, cfg)
    assert (refusal == '') if not refused else (refused in refusal), refusal


def _dev_chain_lost_in_place(*overrides: str) -> tuple[list, int, int]:
    """Stream the dev chain with scan 5 replaced by a 3-point scan; (steps, right, wrong)."""
    from dev_pairs import dev_pair_files
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import load_pair

    pairs = [load_pair(path) for path in dev_pair_files()]  # skips without them
    scans = [(pairs[0].pts_src, pairs[0].label_src)] + [(p.pts_dst, p.label_dst) for p in pairs]
    poses = [np.eye(4)]
    for pair in pairs:
        poses.append(poses[-1] @ np.linalg.inv(pair.trans_gt))
    config = RegistrationConfig().replace(parse_overrides(['threads=1', *overrides]))
    odometry = Odometry(Registration(config))
    degenerate = (np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [5.0, 5.0, 1.0]]), np.full(3, 40))
    steps, last, right, wrong = [], None, 0, 0
    for k, scan in enumerate(scans):
        points, labels = degenerate if k == 5 else scan
        step = odometry.process(points, labels, (k + 1) * 100_000_000)
        steps.append(step)
        if k == 5 or not step.accepted:
            continue
        if last is not None:
            truth = np.linalg.inv(poses[last[0]]) @ poses[k]
            error = np.linalg.solve(truth, np.linalg.inv(last[1]) @ step.pose)
            if np.linalg.norm(error[:3, 3]) > 0.6 or rotation_angle_deg(error) > 5.0:
                wrong += 1
                continue
        right += 1
        last = (k, step.pose)
    return steps, right, wrong


@pytest.mark.slow
def test_the_scan_after_a_lost_one_registers_on_the_dev_chain() -> None:
    """Scan 6, 40 m from the map, is accepted by the seeded search; then 10 right, 0 wrong."""
    steps, right, wrong = _dev_chain_lost_in_place()
    assert steps[6].accepted and 'seeded search' in steps[6].reason, steps[6].reason
    assert wrong == 0 and right == 10, (right, wrong, [s.reason[:200] for s in steps])


@pytest.mark.slow
def test_without_the_seeded_search_the_chain_stalls() -> None:
    """The same stream with odometry.seeded_search false: scan 6 refused, 0 wrong."""
    steps, right, wrong = _dev_chain_lost_in_place('odometry.seeded_search=false')
    assert not steps[6].accepted and wrong == 0, (right, wrong)
