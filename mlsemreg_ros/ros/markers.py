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
``mlsemreg/correspondences``: the registration drawn as a MarkerArray for rviz.

Namespaces: ``inliers`` (green LINE_LIST), ``outliers`` (red LINE_LIST, when
asked), ``landmarks`` (SPHERE_LIST of the current scan's BMR-SS landmark
centroids, coloured by class). Everything is drawn in the current scan's
frame: keyframe keypoints are moved there with the inverse of the result's
``T_keyframe_current`` (display only; no registration geometry here).
"""

from __future__ import annotations

import colorsys

from geometry_msgs.msg import Point
from mlsemreg_ros.core.results import Landmarks, RegistrationResult
import numpy as np
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

#: SemanticKITTI colours (RGB, 0-1) of the landmark-like classes; others get a hue by id.
CLASS_COLORS: dict[str, tuple[float, float, float]] = {
    'car': (0.39, 0.59, 0.96),
    'truck': (0.31, 0.12, 0.71),
    'other-vehicle': (0.31, 0.12, 0.71),
    'person': (1.0, 0.12, 0.12),
    'building': (1.0, 0.78, 0.0),
    'fence': (1.0, 0.47, 0.2),
    'vegetation': (0.0, 0.69, 0.0),
    'trunk': (0.53, 0.24, 0.0),
    'pole': (1.0, 0.94, 0.59),
    'traffic-sign': (1.0, 0.0, 0.0),
}

LINE_WIDTH_M = 0.05
SPHERE_DIAMETER_M = 0.8


def class_color(name: str, learning_id: int) -> ColorRGBA:
    """Display colour of a class (SemanticKITTI palette, else a hue from its id)."""
    r, g, b = CLASS_COLORS.get(name) or colorsys.hsv_to_rgb((learning_id * 0.13) % 1.0, 0.8, 1.0)
    return ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0)


def to_points(xyz: np.ndarray) -> list[Point]:
    """(K, 3) array -> list of geometry_msgs/Point."""
    return [Point(x=x, y=y, z=z) for x, y, z in np.asarray(xyz, dtype=np.float64).tolist()]


def evenly(count: int, cap: int) -> np.ndarray:
    """Up to ``cap`` indices spread evenly over ``range(count)`` (all when count <= cap)."""
    if count <= cap:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, cap).round().astype(np.int64))


def _marker(header: Header, ns: str, kind: int, scale: float, rgba: tuple) -> Marker:
    marker = Marker(header=header, ns=ns, id=0, type=kind, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = scale
    marker.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
    return marker


def _lines(
    header: Header, ns: str, a: np.ndarray, b: np.ndarray, rgba: tuple, max_lines: int
) -> Marker | None:
    """LINE_LIST from a[k] to b[k] (each (K, 3)); None when there is nothing to draw."""
    keep = evenly(a.shape[0], max_lines)
    if keep.size == 0:
        return None
    pairs = np.empty((2 * keep.size, 3))
    pairs[0::2], pairs[1::2] = a[keep], b[keep]
    marker = _marker(header, ns, Marker.LINE_LIST, LINE_WIDTH_M, rgba)
    marker.points = to_points(pairs)
    return marker


def correspondence_markers(
    header: Header,
    result: RegistrationResult,
    landmarks: Landmarks,
    class_names: tuple[str, ...],
    *,
    publish_outliers: bool,
    max_lines: int,
) -> MarkerArray:
    """
    Draw one registration as a MarkerArray in the current scan's frame (``header``).

    ``result.source_points`` are current-scan keypoints, ``result.target_points``
    keyframe keypoints; ``result.transform`` is ``T_keyframe_current``. At most
    ``max_lines`` lines per namespace are drawn (evenly subsampled).
    """
    rotation, translation = result.transform[:3, :3], result.transform[:3, 3]
    keyframe_in_current = (result.target_points - translation) @ rotation  # R^T (q - t)
    current = result.source_points
    inl = result.inlier_mask
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    drawn = [
        _lines(
            header,
            'inliers',
            keyframe_in_current[inl],
            current[inl],
            (0.1, 0.9, 0.1, 0.9),
            max_lines,
        )
    ]
    if publish_outliers:
        drawn.append(
            _lines(
                header,
                'outliers',
                keyframe_in_current[~inl],
                current[~inl],
                (0.9, 0.1, 0.1, 0.5),
                max_lines,
            )
        )
    if len(landmarks):
        spheres = _marker(
            header, 'landmarks', Marker.SPHERE_LIST, SPHERE_DIAMETER_M, (1.0, 1.0, 1.0, 1.0)
        )
        spheres.points = to_points(landmarks.centroids)
        palette = {
            int(c): class_color(class_names[int(c)], int(c)) for c in np.unique(landmarks.classes)
        }
        spheres.colors = [palette[c] for c in landmarks.classes.tolist()]
        drawn.append(spheres)
    markers += [m for m in drawn if m is not None]
    return MarkerArray(markers=markers)
