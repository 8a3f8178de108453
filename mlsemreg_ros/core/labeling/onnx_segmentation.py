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
The user's range-image segmentation network as a label source (``label_source: onnx``).

A RangeNet++ (Milioto et al., IROS 2019), SalsaNext or CENet network exported to ONNX
labels a scan in five steps (docs/onnx_labels.md), all vectorised over the points:

1. **Spherical projection** (:func:`project`): each point falls into the pixel
   ``(row, col)`` of an ``height x width`` image, rows spanning the elevations from
   ``fov_up`` (row 0) to ``fov_down``, columns the azimuth from -180 deg (column 0)
   clockwise; a pixel keeps its nearest point.
2. **Input** (:func:`range_image`): five channels (range, x, y, z, remission) per pixel,
   each normalised by the model's mean and standard deviation; empty pixels are 0.
3. **Inference**: ONNX Runtime, the CPU provider by default, CUDA when onnxruntime-gpu is
   installed; the argmax over the class scores.
4. **Back-projection** (:func:`knn_clean_up`): RangeNet++'s KNN clean-up. Each point
   compares its range with the ranges of its pixel's ``knn_search x knn_search`` window
   (its own pixel: its own range); the ``knn`` closest, weighed by one minus a Gaussian of
   the pixel offset, vote with their pixel's class, unless farther than ``knn_cutoff``.
   The unlabeled class 0 does not vote. Two differences from RangeNet++: the window wraps
   around in azimuth (the image is a full turn) and rows beyond the image are empty rather
   than zero-range pixels; a point without any vote keeps its own pixel's class instead of
   class 1.
5. **Class map**: the network's class index -> SemanticKITTI raw id (default: the learning
   ids of config/labels/semantic_kitti.yaml -> their raw ids, ``learning_map_inv``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.labeling.onnx_config import OnnxLabelsConfig
from mlsemreg_ros.core.resources import share_file
from mlsemreg_ros.core.settings import ConfigError
import numpy as np
import onnxruntime
import yaml

#: Input channels of the network: range, x, y, z, remission.
CHANNELS = ('range', 'x', 'y', 'z', 'remission')
#: Largest raw id a class map may name (raw ids are the lower 16 bits of a label).
MAX_RAW_ID = 0xFFFF
#: Keys of a class-map YAML that hold the index -> raw id mapping, first match wins.
CLASS_MAP_KEYS = ('learning_map_inv', 'learning_to_raw')


@dataclass(frozen=True)
class RangeProjection:
    """Where each point of a scan falls in the range image (:func:`project`)."""

    rows: np.ndarray  # (N,) int64 image row (0: fov_up)
    cols: np.ndarray  # (N,) int64 image column (0: azimuth -180 deg)
    ranges: np.ndarray  # (N,) float64 distance from the sensor, in metres
    pixel_point: np.ndarray  # (H, W) int64: the nearest point in each pixel, -1 if empty

    @property
    def image_range(self) -> np.ndarray:
        """(H, W) float64 range of each pixel's nearest point, inf where empty."""
        filled = self.pixel_point >= 0
        image = np.full(self.pixel_point.shape, np.inf)
        image[filled] = self.ranges[self.pixel_point[filled]]
        return image


def project(points: np.ndarray, section: OnnxLabelsConfig) -> RangeProjection:
    """
    Spherical projection of ``points`` (N, 3) into the ``height x width`` range image.

    Row ``floor((1 - (pitch - fov_down) / (fov_up - fov_down)) * height)`` and column
    ``floor(0.5 * (1 - atan2(y, x) / pi) * width)``, both clamped to the image (points
    above or below the field of view land in the first or last row), as RangeNet++'s
    ``LaserScan.do_range_projection``; a pixel keeps its nearest point.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    height, width = section.height, section.width
    ranges = np.linalg.norm(points, axis=1)
    pitch = np.arcsin(np.clip(points[:, 2] / np.maximum(ranges, 1e-9), -1.0, 1.0))
    yaw = -np.arctan2(points[:, 1], points[:, 0])
    fov_down = np.radians(section.fov_down)
    fov = np.radians(section.fov_up) - fov_down
    rows = np.clip(np.floor((1.0 - (pitch - fov_down) / fov) * height), 0, height - 1)
    cols = np.clip(np.floor(0.5 * (yaw / np.pi + 1.0) * width), 0, width - 1)
    rows, cols = rows.astype(np.int64), cols.astype(np.int64)
    pixel = rows * width + cols
    nearest_range = np.full(height * width, np.inf)
    np.minimum.at(nearest_range, pixel, ranges)
    nearest = np.flatnonzero(ranges == nearest_range[pixel])
    count = points.shape[0]
    pixel_point = np.full(height * width, count, dtype=np.int64)
    np.minimum.at(pixel_point, pixel[nearest], nearest)  # the first of equally near points
    pixel_point[pixel_point == count] = -1
    return RangeProjection(rows, cols, ranges, pixel_point.reshape(height, width))


def channel_stats(section: OnnxLabelsConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(means (5,), stds (5,))`` of the input channels (:data:`CHANNELS`)."""
    means = np.array([getattr(section, f'mean_{c}') for c in CHANNELS])
    stds = np.array([getattr(section, f'std_{c}') for c in CHANNELS])
    return means, stds


def range_image(
    points: np.ndarray,
    intensity: np.ndarray | None,
    projection: RangeProjection,
    section: OnnxLabelsConfig,
) -> np.ndarray:
    """
    Build the network's input (5, H, W) float32: range, x, y, z, remission, normalised.

    Each filled pixel holds ``(value - mean) / std`` of its nearest point; empty pixels are
    0 (RangeNet++ multiplies the normalised image by the projection mask). The remission
    is ``intensity * remission_scale``; without intensity, the mean remission (0 after
    normalisation).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    means, stds = channel_stats(section)
    pixel_point = projection.pixel_point.reshape(-1)
    filled = np.flatnonzero(pixel_point >= 0)
    nearest = pixel_point[filled]
    if intensity is None:
        remission = np.full(nearest.shape[0], means[4])
    else:
        remission = np.asarray(intensity, dtype=np.float64).reshape(-1)[nearest]
        remission = remission * section.remission_scale
    values = np.column_stack([projection.ranges[nearest], points[nearest], remission])
    image = np.zeros((len(CHANNELS), pixel_point.shape[0]), dtype=np.float32)
    image[:, filled] = ((values - means) / stds).T
    return image.reshape(len(CHANNELS), *projection.pixel_point.shape)


def window_weights(search: int, sigma: float) -> np.ndarray:
    """
    (search * search,) one minus the normalised Gaussian of each window offset, row-major.

    RangeNet++'s ``1 - get_gaussian_kernel``: range differences to the nearer pixels count
    less.
    """
    offsets = np.arange(search) - (search - 1) / 2.0
    squared = offsets[:, None] ** 2 + offsets[None, :] ** 2
    kernel = np.exp(-squared / (2.0 * sigma**2))
    return (1.0 - kernel / kernel.sum()).reshape(-1)


def knn_clean_up(
    pixel_classes: np.ndarray,
    projection: RangeProjection,
    knn: int,
    search: int,
    sigma: float,
    cutoff: float,
    compiled: bool | None = None,
) -> np.ndarray:
    """
    Class index of every point (N,) int64 from the image's classes (H, W), RangeNet++'s KNN.

    See the module docstring (step 4). ``knn`` 0 reads each point's own pixel. Among equal
    distances the earlier window pixel (row-major) is nearer; ties between classes go to the
    smaller index, as RangeNet++'s argmax over the votes. ``compiled``: the numba kernel
    (None: when available, core/features/kernels.py), else NumPy; both give the same classes.
    """
    pixel_classes = np.asarray(pixel_classes, dtype=np.int64)
    own = pixel_classes[projection.rows, projection.cols]
    if knn == 0 or own.shape[0] == 0:
        return own
    half = search // 2
    # The images padded by half a window: columns wrapped around, empty rows above and below.
    rows, cols = ((half, half), (0, 0)), ((0, 0), (half, half))
    image_range = np.pad(projection.image_range.astype(np.float32), cols, mode='wrap')
    image_range = np.pad(image_range, rows, constant_values=np.inf).reshape(-1)
    classes = np.pad(np.pad(pixel_classes, cols, mode='wrap'), rows).reshape(-1)
    padded_width = pixel_classes.shape[1] + 2 * half
    window = (np.arange(search)[:, None] * padded_width + np.arange(search)).reshape(-1)
    corner = projection.rows * padded_width + projection.cols  # the window's top left
    ranges = projection.ranges.astype(np.float32)
    weights = window_weights(search, sigma).astype(np.float32)
    # Farther neighbours do not vote, nor do empty pixels (inf) with or without a cutoff.
    limit = np.float32(cutoff) if cutoff > 0 else np.finfo(np.float32).max
    if kernels.use_compiled(compiled):
        num_classes = int(pixel_classes.max()) + 1
        return _knn_vote_kernel(
            image_range, classes, corner, ranges, window, weights, knn, limit, own, num_classes
        )
    flat = corner[:, None] + window  # (N, S*S) pixels of each point's window, row-major
    distance = image_range[flat]
    distance[:, search * search // 2] = ranges  # the point itself
    distance -= ranges[:, None]
    np.abs(distance, out=distance)
    distance *= weights
    nearest = np.argsort(distance, axis=1, kind='stable')[:, :knn]
    nearest_distance = np.take_along_axis(distance, nearest, axis=1)
    votes = classes[np.take_along_axis(flat, nearest, axis=1)]  # (N, knn)
    valid = (nearest_distance <= limit) & (votes > 0)  # the unlabeled class does not vote
    # The mode of each point's valid votes, the smaller class on ties.
    support = ((votes[:, :, None] == votes[:, None, :]) & valid[:, None, :]).sum(axis=2)
    support[~valid] = 0
    winner = np.argmax(support * (int(pixel_classes.max()) + 1) - votes, axis=1)[:, None]
    best = np.take_along_axis(votes, winner, axis=1)[:, 0]
    return np.where(support.max(axis=1) > 0, best, own)


@kernels.jit
def _knn_vote_kernel(
    image_range: np.ndarray,
    classes: np.ndarray,
    corner: np.ndarray,
    ranges: np.ndarray,
    window: np.ndarray,
    weights: np.ndarray,
    knn: int,
    limit: np.float32,
    own: np.ndarray,
    num_classes: int,
) -> np.ndarray:
    """:func:`knn_clean_up`'s votes in one loop over the points (the same arithmetic)."""
    size = window.shape[0]
    center = size // 2
    out = np.empty(corner.shape[0], dtype=np.int64)
    near_distance = np.empty(knn, dtype=np.float32)  # the knn nearest so far, nearest first
    near_pixel = np.empty(knn, dtype=np.int64)
    counts = np.zeros(num_classes, dtype=np.int64)
    for i in range(corner.shape[0]):
        kept = 0
        for j in range(size):
            pixel = corner[i] + window[j]
            value = ranges[i] if j == center else image_range[pixel]
            distance = abs(value - ranges[i]) * weights[j]
            if kept == knn and not distance < near_distance[knn - 1]:
                continue  # an equal distance keeps the earlier pixel
            slot = kept if kept < knn else knn - 1
            while slot > 0 and distance < near_distance[slot - 1]:
                near_distance[slot] = near_distance[slot - 1]
                near_pixel[slot] = near_pixel[slot - 1]
                slot -= 1
            near_distance[slot] = distance
            near_pixel[slot] = pixel
            kept = min(kept + 1, knn)
        for m in range(kept):
            vote = classes[near_pixel[m]]
            if near_distance[m] <= limit and vote > 0:
                counts[vote] += 1
        best, support = own[i], 0
        for k in range(1, num_classes):
            if counts[k] > support:
                best, support = k, counts[k]
            counts[k] = 0
        out[i] = best
    return out


def load_class_map(path: str | Path | None = None) -> np.ndarray:
    """
    (K,) int64 raw id of each class index of the network, from a class-map YAML.

    The YAML holds a ``learning_map_inv`` (lidar-bonnetal's data_cfg) or a
    ``learning_to_raw`` mapping (config/labels/semantic_kitti.yaml, the default), or is
    itself a mapping ``index: raw id``. Indices not named map to 0 (unlabeled).
    """
    path = Path(path).expanduser() if path else share_file('config/labels/semantic_kitti.yaml')
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise ConfigError(f'onnx_labels.class_map: cannot read {path}: {error}') from None
    if isinstance(data, dict):
        data = next((data[k] for k in CLASS_MAP_KEYS if k in data), data)
    if not isinstance(data, dict) or not data:
        raise ConfigError(f'onnx_labels.class_map: {path} holds no index -> raw id mapping')
    pairs = list(data.items())
    if not all(isinstance(k, int) and isinstance(v, int) for k, v in pairs):
        raise ConfigError(f'onnx_labels.class_map: {path}: indices and raw ids must be integers')
    if not all(k >= 0 and 0 <= v <= MAX_RAW_ID for k, v in pairs):
        raise ConfigError(
            f'onnx_labels.class_map: {path}: indices must be >= 0 and raw ids in 0..{MAX_RAW_ID}'
        )
    lut = np.zeros(max(k for k, _ in pairs) + 1, dtype=np.int64)
    for index, raw in pairs:
        lut[index] = raw
    return lut


def execution_providers(choice: str) -> list[str]:
    """ONNX Runtime providers for ``onnx_labels.provider`` (ConfigError for cuda without GPU)."""
    cuda = 'CUDAExecutionProvider' in onnxruntime.get_available_providers()
    if choice == 'cuda' and not cuda:
        raise ConfigError(
            'onnx_labels.provider cuda, but ONNX Runtime has no CUDA provider here '
            '(install onnxruntime-gpu instead of onnxruntime)'
        )
    if choice != 'cpu' and cuda:
        return ['CUDAExecutionProvider', 'CPUExecutionProvider']
    return ['CPUExecutionProvider']


class OnnxSegmenter:
    """Labels scans with the user's range-image network (module docstring)."""

    def __init__(
        self,
        section: OnnxLabelsConfig,
        session: onnxruntime.InferenceSession,
        class_map: np.ndarray,
    ) -> None:
        self.section = section
        self.session = session
        self.class_map = np.asarray(class_map, dtype=np.int64)
        model_input = session.get_inputs()[0]
        self.input_name = model_input.name
        self.input_dtype = np.float16 if model_input.type == 'tensor(float16)' else np.float32
        self.output_name = session.get_outputs()[0].name
        expected = (1, len(CHANNELS), section.height, section.width)
        shape = list(model_input.shape)
        if len(shape) != 4 or any(
            isinstance(d, int) and d != e for d, e in zip(shape, expected, strict=True)
        ):
            raise ConfigError(
                f'onnx_labels.model takes input {shape}, but the range image is {list(expected)} '
                '(onnx_labels.height, onnx_labels.width; five channels)'
            )

    @classmethod
    def from_config(cls, config: Any) -> OnnxSegmenter:
        """
        Build from a RegistrationConfig (its ``onnx_labels`` and ``threads``) or the section.

        Raises ConfigError when the section is invalid or the model does not fit it.
        """
        section = getattr(config, 'onnx_labels', config)
        errors = section.check()
        if errors:
            raise ConfigError('; '.join(errors))
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = int(getattr(config, 'threads', 0))
        options.log_severity_level = 3  # errors only
        providers = execution_providers(section.provider)
        try:
            session = onnxruntime.InferenceSession(
                str(Path(section.model).expanduser()), sess_options=options, providers=providers
            )
        except Exception as error:  # ONNX Runtime's errors derive from Exception only
            raise ConfigError(f'onnx_labels.model {section.model!r}: {error}') from None
        return cls(section, session, load_class_map(section.class_map))

    @property
    def providers(self) -> list[str]:
        """Return the execution providers the session runs on, preferred first."""
        return list(self.session.get_providers())

    def predict(self, image: np.ndarray) -> np.ndarray:
        """(H, W) int64 class index of each pixel of the input image (5, H, W)."""
        feed = {self.input_name: image[None].astype(self.input_dtype, copy=False)}
        output = np.asarray(self.session.run([self.output_name], feed)[0])
        size = (self.section.height, self.section.width)
        if output.ndim == 4 and output.shape[0] == 1 and output.shape[2:] == size:
            return output[0].argmax(axis=0).astype(np.int64)
        if output.dtype.kind in 'iu' and output.size == size[0] * size[1]:
            return output.reshape(size).astype(np.int64)  # a model that exports its argmax
        raise RuntimeError(
            f'onnx_labels.model returned {output.dtype} {list(output.shape)}; expected scores '
            f'[1, C, {size[0]}, {size[1]}] or class indices [1, {size[0]}, {size[1]}]'
        )

    def labels(self, points: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        """
        Label every point of ``points`` (N, 3): its SemanticKITTI raw id, (N,) int32.

        ``intensity`` (N,) or None; a point with a non-finite coordinate gets 0.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        raw = np.zeros(points.shape[0], dtype=np.int32)
        finite = np.flatnonzero(np.isfinite(points).all(axis=1))
        if finite.shape[0] == 0:
            return raw
        usable = points[finite]
        if intensity is not None:
            intensity = np.asarray(intensity, dtype=np.float64).reshape(-1)[finite]
            intensity = np.where(np.isfinite(intensity), intensity, 0.0)
        section = self.section
        projection = project(usable, section)
        pixel_classes = self.predict(range_image(usable, intensity, projection, section))
        classes = knn_clean_up(
            pixel_classes,
            projection,
            section.knn,
            section.knn_search,
            section.knn_sigma,
            section.knn_cutoff,
        )
        class_map = self.class_map
        known = classes < class_map.shape[0]
        raw[finite] = np.where(known, class_map[np.minimum(classes, class_map.shape[0] - 1)], 0)
        return raw
