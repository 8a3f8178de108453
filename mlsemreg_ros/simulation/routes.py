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
Planned routes of field mode: the loop that drives the same streets again.

``loop`` (for loop closure and relocalization) starts on a street heading east and
makes, at successive intersections, the turns :data:`LOOP_TURNS`:

1. once counter-clockwise around block A, back past the start in the same lane;
2. on around block B (east of A), so the street between A and B is driven
   southwards, the opposite direction of step 1, in the other lane;
3. west along the start street in the opposite direction (past the start in the
   other lane), north along A's west street (opposite again), around block C
   (west of A), and east into the start street: the route ends where it began,
   in the same lane and direction.

The base intersection is the one near the origin with the shortest such loop.
The geometry (right-hand lane, filleted turns) is the clean random walk's
(:func:`mlsemreg_ros.simulation.trajectory.plan_route`).
"""

from __future__ import annotations

from mlsemreg_ros.simulation.trajectory import Path2D, TrajectoryConfig
from mlsemreg_ros.simulation.world import StreetGrid
import numpy as np

_DIRECTIONS = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])

#: Turn at each successive intersection: L(eft), R(ight), S(traight).
LOOP_TURNS = 'LLLLSLLLRRLLLS'


def _right(direction: np.ndarray) -> np.ndarray:
    return np.array([direction[1], -direction[0]], dtype=np.float64)


def plan_turns(
    grid: StreetGrid,
    base: tuple[int, int],
    turns: str,
    start_fraction: float,
    config: TrajectoryConfig,
    tail: float,
) -> tuple[Path2D, float]:
    """
    Drive ``turns`` from the edge east of intersection ``base``, back to the start.

    Starts ``start_fraction`` of the way along that edge, heading east in the
    right lane; returns the path (ending ``tail`` metres past the start point) and
    the arc length at which the start point is reached again.
    """
    lane, radius = config.lane_offset, config.turn_radius
    node = np.array(base)
    heading = 0
    a = _DIRECTIONS[heading].astype(np.float64)
    edge = grid.intersection(*(node + _DIRECTIONS[0])) - grid.intersection(*node)
    start = grid.intersection(*node) + start_fraction * edge + lane * _right(a)
    p = start.copy()
    starts, headings, lengths, curvatures = [], [], [], []
    for turn in turns:
        node = node + _DIRECTIONS[heading]
        if turn == 'S':
            continue
        new = (heading + (1 if turn == 'L' else -1)) % 4
        b = _DIRECTIONS[new].astype(np.float64)
        corner = grid.intersection(*node) + lane * (_right(a) + _right(b))
        straight = float(np.dot(corner - radius * a - p, a))
        if straight < 0.0:
            raise ValueError(f'turn radius {radius} m too large for the block at {node}')
        yaw = float(np.arctan2(a[1], a[0]))
        for piece in (
            (p, yaw, straight, 0.0),
            (
                corner - radius * a,
                yaw,
                0.5 * np.pi * radius,
                (1.0 if turn == 'L' else -1.0) / radius,
            ),
        ):
            starts.append(np.asarray(piece[0], dtype=np.float64).copy())
            headings.append(piece[1])
            lengths.append(piece[2])
            curvatures.append(piece[3])
        p = corner + radius * b
        a, heading = b, new
    back = float(np.dot(start - p, a))
    if heading != 0 or back <= 0.0 or abs(float(np.dot(start - p, _right(a)))) > 1e-6:
        raise ValueError('the turn sequence does not end on the start street, heading east')
    starts.append(p.copy())
    headings.append(float(np.arctan2(a[1], a[0])))
    lengths.append(back + tail)
    curvatures.append(0.0)
    path = Path2D(
        np.asarray(starts), np.asarray(headings), np.asarray(lengths), np.asarray(curvatures)
    )
    return path, path.length - tail


def plan_loop(
    grid: StreetGrid, rng: np.random.Generator, config: TrajectoryConfig, tail: float = 60.0
) -> tuple[Path2D, float]:
    """Plan the shortest :data:`LOOP_TURNS` route from an intersection near the origin."""
    best = None
    fraction = float(rng.uniform(0.35, 0.65))
    for di in range(-2, 3):
        for dj in range(-2, 3):
            base = (grid.origin + di, grid.origin + dj)
            path, loop_length = plan_turns(grid, base, LOOP_TURNS, fraction, config, tail)
            if best is None or loop_length < best[1]:
                best = (path, loop_length)
    assert best is not None
    return best
