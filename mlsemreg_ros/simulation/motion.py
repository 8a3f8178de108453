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
Field mode's continuous-time drive: motion profiles and the pose at any instant.

The clean simulator samples the pose once per frame. Field mode needs the pose at
every column of a sweep and at the IMU rate, so the drive is a function of time:

- the speed profile is the clean one (turn speed ``sqrt(a_lat R)``, bounded
  acceleration and braking, on a 0.1 m grid), plus, in the ``aggressive`` and
  ``handheld`` profiles, full stops with a dwell time (stop-and-go, a walker's pauses);
- the arc length ``s(t)`` interpolates the (time, arc length) knots of that
  profile monotonically (PCHIP), so speed is continuous and never negative;
- the pose at ``s`` is the clean one (lane wobble, pitch, roll, bounce with the
  same seeded phases), except that the lane wobble fades out near turns so that
  speed and acceleration stay continuous where the curvature steps.

The ``handheld`` profile walks (1.4 m/s, tight corners) and adds the hand's own motion,
a function of time (:class:`HandSway`): yaw sweeps as the walker looks around, pitch and
roll sway, and each footstep's bob and rock; it goes on while the walker stands.

IMU and wheel odometry are derived from this function (:mod:`.inertial`), so they
agree with the ground truth by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from mlsemreg_ros.simulation.trajectory import euler_to_matrix, Path2D, TrajectoryConfig
import numpy as np
from scipy.interpolate import PchipInterpolator


@dataclass(frozen=True)
class HandSway:
    """
    A hand-held sensor's motion on top of the walk: sines of time (degrees, metres, Hz).

    Peak rates: yaw ``2 pi yaw_deg yaw_hz`` (53 deg/s; with a 2.5 m corner walked at
    1.4 m/s, 32 deg/s, at most 86 deg/s), pitch 16 deg/s and roll 10 deg/s at most; the
    footsteps' bob is 2.5 cm at 1.8 Hz (3.2 m/s^2 vertical).
    """

    yaw_deg: float = 17.0  # looking around
    yaw_hz: float = 0.5
    pitch_deg: float = 4.0
    pitch_hz: float = 0.3
    roll_deg: float = 3.0
    roll_hz: float = 0.23
    step_hz: float = 1.8  # footsteps per second
    step_bob: float = 0.025  # metres up and down, once per step
    step_pitch_deg: float = 0.6  # nod, once per step
    step_roll_deg: float = 1.0  # rock from foot to foot, once per two steps

    def offsets(
        self, t: np.ndarray, phases: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(yaw, pitch, roll, z)`` (n,) radians and metres at times ``t`` (n,) seconds."""
        tau, p = 2.0 * np.pi, phases
        step = tau * self.step_hz * t + p[3]
        yaw = np.radians(self.yaw_deg) * np.sin(tau * self.yaw_hz * t + p[0])
        pitch = np.radians(self.pitch_deg) * np.sin(tau * self.pitch_hz * t + p[1])
        pitch += np.radians(self.step_pitch_deg) * np.sin(step)
        roll = np.radians(self.roll_deg) * np.sin(tau * self.roll_hz * t + p[2])
        roll += np.radians(self.step_roll_deg) * np.sin(0.5 * step)
        return yaw, pitch, roll, self.step_bob * np.cos(step)


@dataclass(frozen=True)
class MotionProfile:
    """How the car is driven (speeds m/s, accelerations m/s^2, lengths m, times s)."""

    name: str
    cruise_speed: float
    max_lateral_accel: float
    max_accel: float
    max_decel: float
    turn_radius: float
    turn_probability: float
    stop_spacing: tuple[float, float] | None = None  # distance between full stops
    stop_dwell: tuple[float, float] = (0.0, 0.0)  # standing time at a stop
    sway: HandSway | None = None  # a hand-held sensor's own motion
    mount_height: float | None = None  # metres above the ground (None: the sensor's)

    def trajectory_config(self, base: TrajectoryConfig | None = None) -> TrajectoryConfig:
        """Return the clean route and motion parameters with this profile's values."""
        return replace(
            base if base is not None else TrajectoryConfig(),
            max_lateral_accel=self.max_lateral_accel,
            max_accel=self.max_accel,
            max_decel=self.max_decel,
            turn_radius=self.turn_radius,
            turn_probability=self.turn_probability,
        )


#: The clean simulator's driving: 10 m/s, 4 m/s^2 in turns, no stops.
NORMAL = MotionProfile('normal', 10.0, 4.0, 2.5, 3.5, 7.0, 0.5)
#: Stop-and-go with sharp turns at speed: 14 m/s, 8 m/s^2 laterally (7.3 m/s and
#: 70 deg/s in a 6.5 m turn), 4.5 m/s^2 up, 7.5 m/s^2 braking, a stop every 35-80 m.
AGGRESSIVE = MotionProfile(
    'aggressive', 14.0, 8.0, 4.5, 7.5, 6.5, 0.7, stop_spacing=(35.0, 80.0), stop_dwell=(0.3, 1.5)
)
#: Walking with the sensor in hand, 1.4 m above the street: 1.4 m/s, 2.5 m corners, a pause
#: of 0.5-2 s every 25-60 m, and :class:`HandSway` (yaw up to 86 deg/s, sway, footsteps).
HANDHELD = MotionProfile(
    'handheld',
    1.4,
    1.0,
    0.8,
    1.0,
    2.5,
    0.5,
    stop_spacing=(25.0, 60.0),
    stop_dwell=(0.5, 2.0),
    sway=HandSway(),
    mount_height=1.4,
)
PROFILES: dict[str, MotionProfile] = {p.name: p for p in (NORMAL, AGGRESSIVE, HANDHELD)}


def motion_profile(name: str) -> MotionProfile:
    """Return the profile called ``name``; ValueError naming the known ones otherwise."""
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f'unknown profile {name!r}; use one of {sorted(PROFILES)}') from None


def speed_profile(
    path: Path2D,
    cruise_speed: float,
    config: TrajectoryConfig,
    stops: np.ndarray,
    dwell: np.ndarray,
    resolution: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Knots ``(times, arc lengths)`` of the drive along ``path`` (both increasing, s from 0).

    Speed is limited in turns and by bounded acceleration and braking (as the clean
    :func:`~mlsemreg_ros.simulation.trajectory.frame_positions`); it is zero at the
    arc lengths ``stops`` (k,), where the car stands ``dwell`` (k,) seconds.
    """
    grid = np.arange(0.0, path.length + resolution, resolution)
    curvature = np.abs(path.curvature(grid))
    speed = np.minimum(
        np.sqrt(config.max_lateral_accel / np.maximum(curvature, 1e-9)), cruise_speed
    )
    stop_index = np.unique(np.clip(np.round(stops / resolution).astype(int), 1, grid.size - 1))
    speed[stop_index] = 0.0
    for i in range(1, grid.size):  # bounded acceleration
        speed[i] = min(speed[i], np.sqrt(speed[i - 1] ** 2 + 2 * config.max_accel * resolution))
    for i in range(grid.size - 2, -1, -1):  # bounded braking
        speed[i] = min(speed[i], np.sqrt(speed[i + 1] ** 2 + 2 * config.max_decel * resolution))
    mean = np.maximum(0.5 * (speed[1:] + speed[:-1]), 1e-3)
    times = np.concatenate([[0.0], np.cumsum(resolution / mean)])
    if stop_index.size == 0:
        return times, grid
    # A stop: two knots at the same arc length, ``dwell`` seconds apart.
    waits = np.zeros(grid.size)
    waits[stop_index] = dwell[: stop_index.size]
    times = times + np.concatenate([[0.0], np.cumsum(waits)[:-1]])
    knots_t = np.concatenate([times, times[stop_index] + waits[stop_index]])
    knots_s = np.concatenate([grid, grid[stop_index]])
    order = np.lexsort((knots_t, knots_s))
    return knots_t[order], knots_s[order]


#: Distance over which the lane wobble fades out before and after a turn, metres.
WOBBLE_FADE_M = 10.0


class ContinuousDrive:
    """
    The sensor pose ``T_world_sensor`` at any time of a drive along a planned path.

    ``phases`` (4,) are the wobble, pitch, roll and bounce phases (the clean
    simulator draws them from ``rng([seed, 4])``); a hand's ``sway`` uses them too.
    Times beyond the drive clamp to its ends (the sway goes on).
    """

    def __init__(
        self,
        path: Path2D,
        cruise_speed: float,
        config: TrajectoryConfig,
        mount_height: float,
        phases: np.ndarray,
        stops: np.ndarray | None = None,
        dwell: np.ndarray | None = None,
        sway: HandSway | None = None,
    ) -> None:
        self.path = path
        self.sway = sway
        self.config = config
        self.mount_height = mount_height
        self.phases = np.asarray(phases, dtype=np.float64)
        stops = np.zeros(0) if stops is None else np.asarray(stops, dtype=np.float64)
        dwell = np.zeros(stops.size) if dwell is None else np.asarray(dwell, dtype=np.float64)
        self.stops = stops
        times, arc = speed_profile(path, cruise_speed, config, stops, dwell)
        self.duration = float(times[-1])
        self._arc = PchipInterpolator(times, arc, extrapolate=False)
        self._knots = (times, arc)

    def arc_length(self, t: np.ndarray) -> np.ndarray:
        """Arc length (n,) in metres at times ``t`` (n,) seconds."""
        return self._arc(np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration))

    def time_at_arc_length(self, s: np.ndarray) -> np.ndarray:
        """First time (n,) at which the car reaches arc length ``s`` (n,)."""
        times, arc = self._knots
        first = np.unique(arc, return_index=True)[1]
        return np.interp(np.asarray(s, dtype=np.float64), arc[first], times[first])

    def _wobble_window(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Weight (n,) of the lane wobble and its slope d/ds: 0 in turns, 1 from 10 m away.

        An offset from a path whose curvature steps would make the speed jump
        (by the factor ``1 - curvature * offset``); fading the wobble out before a
        turn keeps speed and acceleration continuous (the clean simulator keeps it).
        """
        ends = np.cumsum(self.path.lengths)
        turns = self.path.curvatures != 0.0
        if not turns.any():
            return np.ones_like(s), np.zeros_like(s)
        a0, a1 = (ends - self.path.lengths)[turns], ends[turns]
        outside = np.maximum(a0[None] - s[:, None], s[:, None] - a1[None])  # (n, A)
        nearest = np.argmin(outside, axis=1)
        distance = np.maximum(outside[np.arange(s.size), nearest], 0.0)
        side = np.where(s < a0[nearest], -1.0, 1.0)  # d distance / d s
        u = np.clip(distance / WOBBLE_FADE_M, 0.0, 1.0)
        weight = u * u * (3.0 - 2.0 * u)  # smoothstep
        slope = np.where(u < 1.0, 6.0 * u * (1.0 - u) / WOBBLE_FADE_M, 0.0) * side
        return weight, np.where(distance > 0.0, slope, 0.0)

    def poses(self, t: np.ndarray) -> np.ndarray:
        """Return the world poses ``T_world_sensor`` (n, 4, 4) at times ``t`` (n,), seconds."""
        cfg = self.config
        s = self.arc_length(np.atleast_1d(t))
        xy, yaw = self.path.sample(s)
        phase = self.phases
        wavelength = 2.0 * np.pi / 70.0
        window, window_slope = self._wobble_window(s)
        wave = np.sin(wavelength * s + phase[0])
        wobble = cfg.wobble * window * wave
        normal = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
        xy = xy + wobble[:, None] * normal
        slope = cfg.wobble * (
            window * wavelength * np.cos(wavelength * s + phase[0]) + window_slope * wave
        )
        yaw = yaw + np.arctan(slope)
        pitch = np.radians(cfg.pitch_deg) * np.sin(2.0 * np.pi * s / 23.0 + phase[1])
        roll = np.radians(cfg.roll_deg) * np.sin(2.0 * np.pi * s / 17.0 + phase[2])
        z = self.mount_height + cfg.bounce * np.sin(2.0 * np.pi * s / 5.3 + phase[3])
        if self.sway is not None:
            sway = self.sway.offsets(np.atleast_1d(np.asarray(t, dtype=np.float64)), phase)
            yaw, pitch, roll, z = yaw + sway[0], pitch + sway[1], roll + sway[2], z + sway[3]
        poses = np.tile(np.eye(4), (s.size, 1, 1))
        poses[:, :3, :3] = euler_to_matrix(roll, pitch, yaw)
        poses[:, :2, 3] = xy
        poses[:, 2, 3] = z
        return poses
