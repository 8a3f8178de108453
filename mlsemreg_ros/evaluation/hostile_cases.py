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
The hostile cases of ``mlsemreg fuzz-node``: IMU and wheel streams, per-point time fields.

Each case perturbs a stream that is right (:func:`good_streams`: the gyro and the wheel poses
of a pair's motion) or brings a cloud with a hostile time field; the runner
(``evaluation/hostile_run.py``) then sends three good scans. A prior message is a
``(publish time, fields)`` pair; ``fields`` may override the stamp (``stamp_s``, ``sec`` /
``nanosec``), the values (``gyro``, ``accel``; ``position``, ``quaternion``) and the frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

IMU_PERIOD_S = 0.005  # 200 Hz
WHEEL_PERIOD_S = 0.02  # 50 Hz
NAN, INF = float('nan'), float('inf')

Message = tuple[float, dict[str, Any]]
Modifier = Callable[[list[Message], 'Timeline', np.random.Generator], list[Message]]


@dataclass
class Timeline:
    """The stamps of one case: three good scans ``interval`` apart from ``t0``."""

    t0: float
    interval: float  # s

    @property
    def scans(self) -> list[float]:
        """Return the stamps (s) of the three good scans."""
        return [self.t0 + k * self.interval for k in range(3)]

    @property
    def middle(self) -> float:
        """Return a time inside the moved scan's interval, between two IMU samples."""
        return self.t0 + 1.5 * self.interval + 0.5 * IMU_PERIOD_S


@dataclass
class Case:
    """One hostile input."""

    name: str
    group: str  # imu, wheel, imu+wheel, time field
    imu: list[Message] = field(default_factory=list)  # hostile IMU messages, added
    wheel: list[Message] = field(default_factory=list)  # hostile wheel messages, added
    modify: dict[str, Modifier] = field(default_factory=dict)  # stream -> its good stream
    cloud: dict[str, Any] | None = None  # a hostile time field: on the keyframe's points,
    #                                      sent first, or (``moved``) on the moved scan
    streams: tuple[str, ...] = ('imu', 'wheel')  # good streams around the scans


def pair_motion(T_dst_src: np.ndarray, timeline: Timeline) -> Callable[[float], np.ndarray]:
    """Return the sensor pose at time t: still until ``t1``, then the pair's motion to ``t2``."""
    rotvec = Rotation.from_matrix(T_dst_src[:3, :3]).as_rotvec()
    t1 = timeline.scans[1]

    def pose(t: float) -> np.ndarray:
        s = float(np.clip((t - t1) / timeline.interval, 0.0, 1.0))
        out = np.eye(4)
        out[:3, :3] = Rotation.from_rotvec(rotvec * s).as_matrix()
        out[:3, 3] = T_dst_src[:3, 3] * s
        return out

    return pose


def good_streams(T_dst_src: np.ndarray, timeline: Timeline) -> dict[str, list[Message]]:
    """Return the right IMU (the motion's gyro, gravity) and wheel messages over the case."""
    t0, t1, t2 = timeline.scans
    rate = Rotation.from_matrix(T_dst_src[:3, :3]).as_rotvec() / timeline.interval
    imu = [
        (float(t), {'gyro': rate if t1 < t <= t2 else np.zeros(3)})
        for t in np.arange(t0 - 0.05, t2 + 0.05 + 1e-9, IMU_PERIOD_S)
    ]
    pose = pair_motion(T_dst_src, timeline)
    wheel = [
        (float(t), {'pose': pose(float(t))})
        for t in np.arange(t0 - 0.05, t2 + 0.05 + 1e-9, WHEEL_PERIOD_S)
    ]
    return {'imu': imu, 'wheel': wheel}


def case_streams(
    case: Case, T_dst_src: np.ndarray, timeline: Timeline, rng: np.random.Generator
) -> dict[str, list[Message]]:
    """Return the prior messages of a case per stream, in publishing order."""
    good = good_streams(T_dst_src, timeline)
    out: dict[str, list[Message]] = {}
    for name, hostile in (('imu', case.imu), ('wheel', case.wheel)):
        messages = list(good[name]) if name in case.streams else []
        if name in case.modify:
            messages = case.modify[name](messages, timeline, rng)
        messages += [(t, dict(kw, hostile=True)) for t, kw in hostile]
        messages.sort(key=lambda item: item[0])  # stable: hostile after good at one time
        if messages:
            out[name] = messages
    return out


# -- modifiers of a good stream ---------------------------------------------------------------
def _shuffle(messages: list[Message], timeline: Timeline, rng: np.random.Generator):
    """Publish the moved interval's messages in random order (stamps kept)."""
    t1, t2 = timeline.scans[1:]
    inside = [k for k, (t, _) in enumerate(messages) if t1 < t <= t2]
    order = rng.permutation(inside)
    out = list(messages)
    for slot, k in zip(inside, order, strict=True):
        out[slot] = (messages[slot][0], dict(messages[k][1], stamp_s=messages[k][0]))
    return out


def _shift_from(seconds: float) -> Modifier:
    """Stamp every message after the scan at ``t1`` ``seconds`` later (a stream restart)."""

    def modify(messages: list[Message], timeline: Timeline, rng: np.random.Generator):
        t1 = timeline.scans[1]
        return [(t, dict(kw, stamp_s=t + seconds) if t > t1 else kw) for t, kw in messages]

    return modify


def _gyro_offset(offset: tuple[float, float, float]) -> Modifier:
    """Add a plausible but wrong rate to every gyro sample."""

    def modify(messages: list[Message], timeline: Timeline, rng: np.random.Generator):
        return [(t, dict(kw, gyro=np.asarray(kw['gyro']) + offset)) for t, kw in messages]

    return modify


def _wheel_reset(offset: tuple[float, float, float]) -> Modifier:
    """Move every pose after the middle of the interval by ``offset`` (odometry reset)."""

    def modify(messages: list[Message], timeline: Timeline, rng: np.random.Generator):
        out = []
        for t, kw in messages:
            if t > timeline.middle:
                pose = kw['pose'].copy()
                pose[:3, 3] += offset
                kw = dict(kw, pose=pose)
            out.append((t, kw))
        return out

    return modify


def _stuck(messages: list[Message], timeline: Timeline, rng: np.random.Generator):
    """Wheels that slip: every pose the first one (no motion)."""
    return [(t, dict(kw, pose=np.eye(4))) for t, kw in messages]


# -- the cases ----------------------------------------------------------------------------------
def _imu_value_cases(m: float) -> list[Case]:
    out = []
    for label, values in (
        ('NaN gyro', {'gyro': (NAN, 0, 0)}),
        ('inf gyro', {'gyro': (0, INF, 0)}),
        ('-inf accel', {'accel': (0, 0, -INF)}),
        ('NaN accel', {'accel': (NAN, NAN, NAN)}),
        ('gyro 1e6 rad/s', {'gyro': (1e6, 0, 0)}),
        ('gyro 40 rad/s', {'gyro': (0, 0, 40.0)}),
        ('accel 1e300 m/s2', {'accel': (1e300, 0, 0)}),
        ('accel 20 g', {'accel': (0, 0, 20 * 9.81)}),
        ('denormal gyro', {'gyro': (5e-324, -5e-324, 1e-310)}),
        ('largest float gyro', {'gyro': (np.finfo(float).max, 0, 0)}),
        ('plausible gyro spike 30 rad/s', {'gyro': (0, 0, 30.0)}),
        ('frame_id of another sensor', {'frame': 'imu_link_other'}),
    ):
        out.append(Case(f'one: {label}', 'imu', imu=[(m, values)], streams=('imu',)))
    for label, values, count in (
        ('gyro 1e6 rad/s', {'gyro': (1e6, 0, 0)}, 20),
        ('accel 1e300 m/s2', {'accel': (0, 1e300, 0)}, 20),
        ('NaN', {'gyro': (NAN, NAN, NAN)}, 50),
        ('plausible gyro spikes 25 rad/s', {'gyro': (25.0, 0, 0)}, 3),
    ):
        messages = [(m + 0.0002 * k, values) for k in range(count)]
        out.append(Case(f'burst of {count}: {label}', 'imu', imu=messages, streams=('imu',)))
    return out


def _imu_stamp_cases(m: float, timeline: Timeline, rng: np.random.Generator) -> list[Case]:
    def case(name: str, messages: list[Message] = (), **kw: Any) -> Case:
        return Case(name, 'imu', imu=list(messages), streams=('imu',), **kw)

    random_gyro = [(m, {'gyro': rng.uniform(-20, 20, 3)}) for _ in range(200)]
    random_both = [
        (m, {'gyro': rng.uniform(-20, 20, 3), 'accel': rng.uniform(-100, 100, 3)})
        for _ in range(200)
    ]
    spike = {'gyro': (9.0, 0, 0)}
    return [
        case('200 sharing one stamp, random gyro', random_gyro),
        case('200 sharing one stamp, random gyro and accel', random_both),
        case('2000 valid samples sharing one stamp', [(m, {})] * 2000),
        case('stamp 0', [(m, {'sec': 0, 'nanosec': 0, **spike})]),
        case('nanosec 2^32-1', [(m, {'nanosec': 2**32 - 1, **spike})]),
        case('nanosec 1e9', [(m, {'nanosec': 10**9, **spike})]),
        case('negative sec', [(m, {'sec': -5, **spike})]),
        case('sec 2^31-1 (far future)', [(m, {'sec': 2**31 - 1, **spike})]),
        case('stamp 1 s (far past)', [(m, {'sec': 1, 'nanosec': 0, **spike})]),
        case(
            '10 among the stream with stamp 0',
            [(m + 1e-4 * k, {'sec': 0, 'nanosec': 0, **spike}) for k in range(10)],
        ),
        case(
            '10 among the stream with nanosec 2^32-1',
            [(m + 1e-4 * k, {'nanosec': 2**32 - 1, **spike}) for k in range(10)],
        ),
        case('a backward stamp inside the interval', [(m, {'stamp_s': m - 0.03, **spike})]),
        case(
            'a repeated stamp with another gyro',
            [(m, {'stamp_s': m - 0.5 * IMU_PERIOD_S, **spike})],
        ),
        case('the interval shuffled (out of order)', modify={'imu': _shuffle}),
        case('the stream restarts 1 s back', modify={'imu': _shift_from(-1.0)}),
        case('the stream jumps 10 s ahead', modify={'imu': _shift_from(10.0)}),
        case('the gyro off by 1 rad/s throughout', modify={'imu': _gyro_offset((0, 0, 1.0))}),
    ]


def _wheel_cases(m: float, timeline: Timeline) -> list[Case]:
    def case(name: str, messages: list[Message] = (), **kw: Any) -> Case:
        return Case(name, 'wheel', wheel=list(messages), streams=('wheel',), **kw)

    out = [
        case(f'one: {label}', [(m, {'quaternion': q})])
        for label, q in (
            ('zero quaternion', (0, 0, 0, 0)),
            ('NaN quaternion', (NAN, NAN, NAN, NAN)),
            ('w = 1e-300', (0, 0, 0, 1e-300)),
            ('denormal quaternion', (5e-324, 0, 0, 5e-324)),
            ('quaternion of norm 2', (0, 0, 0, 2.0)),
            ('inf orientation', (0, 0, INF, 1)),
            ('quaternion 1e300', (1e300, 1e300, 0, 0)),
            ('heading jump 180 deg', (0, 0, 1.0, 0)),
        )
    ]
    half = timeline.scans[1] + 0.5 * timeline.interval
    out += [
        case('zero quaternion at start-up', [(timeline.t0 - 0.06, {'quaternion': (0, 0, 0, 0)})]),
        case('one: NaN position', [(m, {'position': (NAN, 0, 0)})]),
        case('one: inf position', [(m, {'position': (0, INF, 0)})]),
        case('one: position 1e300', [(m, {'position': (1e300, 0, 0)})]),
        case('one: pose jump 1 km', [(m, {'position': (1000.0, 0, 0)})]),
        case('stamp 0', [(m, {'sec': 0, 'nanosec': 0})]),
        case('nanosec 2^32-1', [(m, {'nanosec': 2**32 - 1})]),
        case('a repeated stamp, another pose', [(half, {'position': (3.0, 1.0, 0)})]),
        case('a backward stamp', [(m, {'stamp_s': m - 0.04, 'position': (-2.0, 0, 0)})]),
        case('2000 messages sharing one stamp', [(m, {})] * 2000),
        case('odometry reset 100 m back', modify={'wheel': _wheel_reset((-100.0, 0, 0))}),
        case('wheels stuck (slip)', modify={'wheel': _stuck}),
        case('the stream restarts 1 s back', modify={'wheel': _shift_from(-1.0)}),
    ]
    return out


#: Per-point time fields: (label, field name, dtype, values, extra).
TIME_FIELD_CASES: tuple[tuple[str, str, str, str, dict], ...] = (
    ('NaN in 1 %', 'time', 'f4', 'nan', {}),
    ('inf in 1 %', 'time', 'f4', 'inf', {}),
    ('all equal', 'time', 'f4', 'equal', {}),
    ('backwards (decreasing)', 'time', 'f4', 'backwards', {}),
    ('huge (1e30)', 'time', 'f4', 'huge', {}),
    ('microseconds in a float field', 'time', 'f4', 'us', {}),
    ('float64 absolute, 1.7e9 s from the stamp', 'timestamp', 'f8', 'far_absolute', {}),
    ('float64 declared past the point step', 'time', 'f8', 'sweep', {'overrun': True}),
    ('uint32 ns spanning 2 s', 't', 'u4', 'span2s', {}),
    ('5 s after the stamp', 'time', 'f4', 'late', {}),
    ('negative (before the sweep end)', 'time', 'f4', 'negative', {}),
    ('count 0', 'time', 'f4', 'sweep', {'count': 0}),
    ('count 3', 'time', 'f4', 'sweep', {'count': 3}),
    ('uint8', 'time', 'u1', 'small', {}),
    ('unknown datatype 42', 'time', 'f4', 'sweep', {'datatype': 42}),
    ('largest float64', 'time', 'f8', 'max', {}),
    ('int32 minimum', 'offset_time', 'i4', 'intmin', {}),
    ('a good sweep (control)', 'time', 'f4', 'sweep', {}),
)


def cases(timeline: Timeline, rng: np.random.Generator) -> list[Case]:
    """Return every hostile case, its messages relative to ``timeline``."""
    m = timeline.middle
    out = _imu_value_cases(m) + _imu_stamp_cases(m, timeline, rng) + _wheel_cases(m, timeline)
    out.append(
        Case(
            'NaN IMU and zero-quaternion wheel together',
            'imu+wheel',
            imu=[(m, {'gyro': (NAN, 0, 0)})],
            wheel=[(m, {'quaternion': (0, 0, 0, 0)})],
        )
    )
    for label, name, dtype, values, extra in TIME_FIELD_CASES:
        spec = {'name': name, 'dtype': dtype, 'values': values, **extra}
        out.append(Case(f'time field: {label}', 'time field', cloud=spec))
    for label, name, dtype, values, extra in TIME_FIELD_CASES:  # on the moved scan itself
        spec = {'name': name, 'dtype': dtype, 'values': values, 'moved': True, **extra}
        out.append(Case(f'moved scan, time field: {label}', 'time field (moved)', cloud=spec))
    return out


def time_values(kind: str, n: int, stamp_s: float, rng: np.random.Generator) -> np.ndarray:
    """Return ``n`` per-point times of a hostile kind, in the field's own unit."""
    sweep = np.sort(rng.uniform(0.0, 0.1, n))
    if kind == 'sweep':
        return sweep
    values = {
        'nan': lambda: np.where(rng.random(n) < 0.01, np.nan, sweep),
        'inf': lambda: np.where(rng.random(n) < 0.01, np.inf, sweep),
        'equal': lambda: np.full(n, 0.05),
        'backwards': lambda: sweep[::-1].copy(),
        'huge': lambda: sweep * 1e31,
        'us': lambda: sweep * 1e6,
        'far_absolute': lambda: stamp_s + 1.7e9 + sweep,
        'span2s': lambda: sweep * 2e10,
        'late': lambda: 5.0 + sweep,
        'negative': lambda: sweep - 0.1,
        'small': lambda: np.round(sweep * 2000),
        'max': lambda: np.full(n, np.finfo(np.float64).max),
        'intmin': lambda: np.full(n, np.iinfo(np.int32).min, dtype=np.float64),
    }
    return values[kind]()


#: PointField datatypes of the time field's dtypes.
_DATATYPES = {'f4': 7, 'f8': 8, 'u4': 6, 'u1': 2, 'i4': 5}


def hostile_cloud(
    msg_classes: tuple[Any, Any],
    header: Any,
    points: np.ndarray,
    labels: np.ndarray,
    spec: dict[str, Any],
    rng: np.random.Generator,
) -> Any:
    """Return a PointCloud2 of ``points`` (x, y, z float32, label uint32) and a time field."""
    cloud_cls, field_cls = msg_classes
    time_dtype = np.dtype(spec['dtype']).newbyteorder('<')
    dtype = np.dtype(
        [('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('label', '<u4'), ('t', time_dtype)]
    )
    packed = np.zeros(len(points), dtype=dtype)
    for k, axis in enumerate('xyz'):
        packed[axis] = points[:, k]
    packed['label'] = labels
    stamp_s = header.stamp.sec + 1e-9 * header.stamp.nanosec
    with np.errstate(all='ignore'):
        packed['t'] = time_values(spec['values'], len(points), stamp_s, rng).astype(time_dtype)
    step = dtype.itemsize
    offset = step - 4 if spec.get('overrun') else dtype.fields['t'][1]
    datatype = spec.get('datatype', _DATATYPES[spec['dtype']])
    fields = [field_cls(name=a, offset=4 * k, datatype=7, count=1) for k, a in enumerate('xyz')]
    fields.append(field_cls(name='label', offset=12, datatype=6, count=1))
    fields.append(
        field_cls(name=spec['name'], offset=offset, datatype=datatype, count=spec.get('count', 1))
    )
    return cloud_cls(
        header=header,
        height=1,
        width=len(points),
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * len(points),
        data=packed.tobytes(),
        is_dense=True,
    )
