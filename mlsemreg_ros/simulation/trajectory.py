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
A smooth drive through the street grid: route planning and sensor poses.

The route is a random walk over the grid's intersections (straight on, left or
right; never a U-turn) in the right-hand lane, with 90-degree turns filleted by
circular arcs. Poses follow the path at a constant distance per frame, with a
small lateral wobble, pitch/roll oscillations and suspension bounce, so the
ground truth is a full 6-DoF trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.simulation.world import StreetGrid
import numpy as np

#: Driving directions on the grid: east, north, west, south (left turn = index + 1).
_DIRECTIONS = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])


@dataclass
class TrajectoryConfig:
    """Route and motion parameters (lengths in metres, angles in degrees)."""

    lane_offset: float = 1.8  # right of the street centre line
    turn_radius: float = 7.0
    turn_probability: float = 0.5  # at every intersection
    max_straight: float = 100.0  # force a turn after this distance without one
    wobble: float = 0.2  # amplitude of the lateral wobble in the lane
    pitch_deg: float = 0.5  # amplitude of the pitch oscillation
    roll_deg: float = 0.35  # amplitude of the roll oscillation
    bounce: float = 0.02  # amplitude of the vertical bounce
    max_lateral_accel: float = 4.0  # m/s^2: the car slows down for turns (v = sqrt(a R))
    max_accel: float = 2.5  # m/s^2, speeding up after a turn
    max_decel: float = 3.5  # m/s^2, braking before a turn


@dataclass
class Path2D:
    """A planar path of constant-curvature pieces (lines and arcs)."""

    starts: np.ndarray  # (P, 2) start point of each piece
    headings: np.ndarray  # (P,) start heading, radians
    lengths: np.ndarray  # (P,) arc length, metres
    curvatures: np.ndarray  # (P,) 1/m, 0 for lines, > 0 for left turns

    @property
    def length(self) -> float:
        """Total length in metres."""
        return float(self.lengths.sum())

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Look up the signed curvature at the arc lengths ``s`` (n,), in 1/m."""
        ends = np.cumsum(self.lengths)
        piece = np.minimum(
            np.searchsorted(ends, np.asarray(s), side='right'), self.lengths.size - 1
        )
        return self.curvatures[piece]

    def sample(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (n, 2) and headings (n,) at arc lengths ``s`` (n,), clipped to the path."""
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self.length)
        ends = np.cumsum(self.lengths)
        piece = np.minimum(np.searchsorted(ends, s, side='right'), self.lengths.size - 1)
        u = s - (ends[piece] - self.lengths[piece])
        h0, k = self.headings[piece], self.curvatures[piece]
        heading = h0 + k * u
        straight = np.abs(k) < 1e-12
        safe_k = np.where(straight, 1.0, k)
        dx = np.where(straight, u * np.cos(h0), (np.sin(heading) - np.sin(h0)) / safe_k)
        dy = np.where(straight, u * np.sin(h0), (np.cos(h0) - np.cos(heading)) / safe_k)
        return self.starts[piece] + np.stack([dx, dy], axis=1), heading

    def waypoints(self, spacing: float = 5.0) -> np.ndarray:
        """Positions (n, 2) every ``spacing`` metres along the path (what a world is built on)."""
        return self.sample(np.arange(0.0, self.length + spacing, spacing))[0]


def _right(direction: np.ndarray) -> np.ndarray:
    return np.array([direction[1], -direction[0]], dtype=np.float64)


def plan_route(
    grid: StreetGrid,
    length: float,
    rng: np.random.Generator,
    config: TrajectoryConfig | None = None,
) -> Path2D:
    """Random walk of at least ``length`` metres in the right lane, starting near the origin."""
    cfg = config if config is not None else TrajectoryConfig()
    lane, radius = cfg.lane_offset, cfg.turn_radius
    node = np.array([grid.origin, grid.origin])
    heading_index = int(rng.integers(4))
    a = _DIRECTIONS[heading_index].astype(np.float64)
    first_edge = np.linalg.norm(
        grid.intersection(*(node + _DIRECTIONS[heading_index])) - grid.intersection(*node)
    )
    p = grid.intersection(*node) + rng.uniform(0.5, 0.75) * first_edge * a + lane * _right(a)
    starts, headings, lengths, curvatures = [], [], [], []
    total, last_turn = 0.0, 0.0
    size = grid.xs.size

    def add(start: np.ndarray, heading: float, piece_length: float, curvature: float) -> None:
        starts.append(start.copy())
        headings.append(heading)
        lengths.append(piece_length)
        curvatures.append(curvature)

    while True:
        node = node + _DIRECTIONS[heading_index]
        center = grid.intersection(*node)
        to_center = float(np.dot(center - p, a))
        if total + to_center - radius - 2.0 >= length:
            add(p, float(np.arctan2(a[1], a[0])), length - total + 1.0, 0.0)
            break
        options = [(heading_index + turn) % 4 for turn in (1, -1)]
        options = [
            d
            for d in options
            if 0 < node[0] + _DIRECTIONS[d][0] < size - 1
            and 0 < node[1] + _DIRECTIONS[d][1] < size - 1
        ]
        ahead = node + _DIRECTIONS[heading_index]
        can_go_straight = 0 < ahead[0] < size - 1 and 0 < ahead[1] < size - 1
        must_turn = total + to_center - last_turn > cfg.max_straight or not can_go_straight
        if options and (must_turn or rng.random() < cfg.turn_probability):
            new_index = options[int(rng.integers(len(options)))]
            b = _DIRECTIONS[new_index].astype(np.float64)
            corner = center + lane * (_right(a) + _right(b))
            straight = float(np.dot(corner - radius * a - p, a))
            heading = float(np.arctan2(a[1], a[0]))
            add(p, heading, straight, 0.0)
            left = (new_index - heading_index) % 4 == 1
            add(
                corner - radius * a,
                heading,
                0.5 * np.pi * radius,
                (1.0 if left else -1.0) / radius,
            )
            total += straight + 0.5 * np.pi * radius
            last_turn = total
            p = corner + radius * b
            a, heading_index = b, new_index
    return Path2D(
        np.asarray(starts), np.asarray(headings), np.asarray(lengths), np.asarray(curvatures)
    )


def euler_to_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotations (n, 3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)`` from angles (n,) in radians."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def frame_positions(
    path: Path2D,
    frames: int,
    step: float,
    config: TrajectoryConfig,
    dt: float = 0.1,
    resolution: float = 0.1,
) -> np.ndarray:
    """
    Return the arc length (F,) of each frame for a car cruising at ``step`` m/frame.

    Frames are ``dt`` seconds apart. The speed (m/s) is limited to
    ``sqrt(max_lateral_accel * R)`` in turns of radius R and changes at most at
    ``max_accel`` / ``max_decel`` (forward and backward passes over a grid of
    ``resolution`` metres), so turns are driven at a realistic yaw rate: 5.3 m/s
    and 43 deg/s in a 7 m turn at 4 m/s^2, against 10 m/s on straights at 1 m/frame.
    """
    grid = np.arange(0.0, path.length + resolution, resolution)
    cruise = step / dt
    curvature = np.abs(path.curvature(grid))
    limit = np.sqrt(config.max_lateral_accel / np.maximum(curvature, 1e-9))
    speed = np.minimum(limit, cruise)
    for i in range(1, grid.size):  # forward pass: bounded acceleration
        speed[i] = min(speed[i], np.sqrt(speed[i - 1] ** 2 + 2 * config.max_accel * resolution))
    for i in range(grid.size - 2, -1, -1):  # backward pass: bounded braking
        speed[i] = min(speed[i], np.sqrt(speed[i + 1] ** 2 + 2 * config.max_decel * resolution))
    time_at = np.concatenate([[0.0], np.cumsum(resolution / (0.5 * (speed[1:] + speed[:-1])))])
    return np.interp(dt * np.arange(frames), time_at, grid)


def sensor_poses(
    path: Path2D,
    frames: int,
    step: float,
    mount_height: float,
    rng: np.random.Generator,
    config: TrajectoryConfig | None = None,
    dt: float = 0.1,
) -> np.ndarray:
    """
    World poses (F, 4, 4) ``T_world_sensor`` of a car cruising at ``step`` m/frame.

    The car slows down for turns (:func:`frame_positions`). The sensor frame is x
    forward, y left, z up, ``mount_height`` above the road.
    """
    cfg = config if config is not None else TrajectoryConfig()
    s = frame_positions(path, frames, step, cfg, dt)
    xy, yaw = path.sample(s)
    phase = rng.uniform(0.0, 2.0 * np.pi, size=4)
    wavelength = 2.0 * np.pi / 70.0
    wobble = cfg.wobble * np.sin(wavelength * s + phase[0])
    normal = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
    xy = xy + wobble[:, None] * normal
    yaw = yaw + np.arctan(cfg.wobble * wavelength * np.cos(wavelength * s + phase[0]))
    pitch = np.radians(cfg.pitch_deg) * np.sin(2.0 * np.pi * s / 23.0 + phase[1])
    roll = np.radians(cfg.roll_deg) * np.sin(2.0 * np.pi * s / 17.0 + phase[2])
    z = mount_height + cfg.bounce * np.sin(2.0 * np.pi * s / 5.3 + phase[3])
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = euler_to_matrix(roll, pitch, yaw)
    poses[:, :2, 3] = xy
    poses[:, 2, 3] = z
    return poses
