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
Message stamps (``builtin_interfaces/Time``) <-> integer nanoseconds, without importing ROS.

Duck-typed on ``sec`` and ``nanosec``: rclpy messages and rosbags typestore messages alike.
Integer nanoseconds are the one internal time unit (``stamp_ns``); seconds appear only
in text (diagnostics, TUM files).
"""

from __future__ import annotations

from typing import Any

NS_PER_S = 1_000_000_000


def stamp_to_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds (exact)."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def stamp_to_seconds(stamp: Any) -> float:
    """``builtin_interfaces/Time`` -> float seconds (for text; not exact)."""
    return stamp.sec + 1e-9 * stamp.nanosec


def ns_to_sec_nanosec(stamp_ns: int) -> tuple[int, int]:
    """Integer nanoseconds -> ``(sec, nanosec)`` of a ``builtin_interfaces/Time``."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return sec, nanosec


def parse_seconds(text: str) -> int:
    """Seconds written as text (``'1700000000.200000000'``) -> exact integer nanoseconds."""
    seconds, _, fraction = text.strip().partition('.')
    return int(seconds) * NS_PER_S + int((fraction + '000000000')[:9])


def format_seconds(stamp_ns: int) -> str:
    """Integer nanoseconds -> exact seconds text ``'<sec>.<nanosec, 9 digits>'``."""
    sec, nanosec = ns_to_sec_nanosec(stamp_ns)
    return f'{sec}.{nanosec:09d}'
