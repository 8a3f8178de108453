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
The ONNX label source (core/labeling/onnx_segmentation.py) with tiny hand-built networks.

The networks are 1x1 convolutions built with ``onnx.helper``: each class score is a linear
function of the normalised input channels, so the class of every pixel, and through the
back-projection of every point, is known in advance.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.labeling.onnx_config import OnnxLabelsConfig
from mlsemreg_ros.core.labeling.onnx_segmentation import (
    knn_clean_up,
    load_class_map,
    OnnxSegmenter,
    project,
    range_image,
    RangeProjection,
    window_weights,
)
import numpy as np
import onnx
from onnx import helper, TensorProto
import pytest

HEIGHT, WIDTH = 4, 8
#: Test image: 4 rows of 10 deg from +10 to -30 deg, 8 columns of 45 deg.
SMALL = OnnxLabelsConfig(height=HEIGHT, width=WIDTH, fov_up=10.0, fov_down=-30.0)

#: Scores (0, z_n - 1, -z_n - 1) of classes 0, 1, 2 (z_n the normalised z): class 1 above
#: mean_z + std_z, class 2 below mean_z - std_z, class 0 between (and on empty pixels).
Z_WEIGHTS = ([[0, 0, 0, 0, 0], [0, 0, 0, 1, 0], [0, 0, 0, -1, 0]], [0.0, -1.0, -1.0])
#: Scores (0, r_n, -r_n): class 1 beyond mean_range, class 2 nearer; empty pixels class 0.
RANGE_WEIGHTS = ([[0, 0, 0, 0, 0], [1, 0, 0, 0, 0], [-1, 0, 0, 0, 0]], [0.0, 0.0, 0.0])


def linear_model(
    path: Path,
    weights: tuple[list[list[float]], list[float]],
    height: int,
    width: int,
    argmax: bool = False,
) -> Path:
    """Write a 1x1 convolution network [1, 5, H, W] -> scores [1, C, H, W] (or its argmax)."""
    kernel, bias = np.asarray(weights[0], np.float32), np.asarray(weights[1], np.float32)
    classes = kernel.shape[0]
    nodes = [helper.make_node('Conv', ['image', 'kernel', 'bias'], ['scores'])]
    output = helper.make_tensor_value_info(
        'scores', TensorProto.FLOAT, [1, classes, height, width]
    )
    if argmax:
        nodes.append(helper.make_node('ArgMax', ['scores'], ['classes'], axis=1, keepdims=0))
        output = helper.make_tensor_value_info('classes', TensorProto.INT64, [1, height, width])
    graph = helper.make_graph(
        nodes,
        'linear_segmentation',
        [helper.make_tensor_value_info('image', TensorProto.FLOAT, [1, 5, height, width])],
        [output],
        initializer=[
            helper.make_tensor(
                'kernel', TensorProto.FLOAT, [classes, 5, 1, 1], kernel.reshape(-1).tolist()
            ),
            helper.make_tensor('bias', TensorProto.FLOAT, [classes], bias.tolist()),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def direction(pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Return the unit vector at an elevation and azimuth (azimuth atan2(y, x))."""
    pitch, yaw = np.radians(pitch_deg), np.radians(yaw_deg)
    return np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])


# -- projection ----------------------------------------------------------------------
def test_projection_puts_points_in_known_pixels() -> None:
    # rows: +5 deg -> 0, -15 deg -> 2 (2.5 rows down), -29 deg -> 3; beyond the FOV clamps.
    # columns floor(4 - azimuth / 45 deg): -10 -> 4, 10 -> 3, 100 -> 1, -100 -> 6, 170 -> 0,
    # -170 -> 7.
    cases = [((5, -10), (0, 4)), ((-15, 100), (2, 1)), ((-29, -100), (3, 6))]
    cases += [((-15, 170), (2, 0)), ((-15, -170), (2, 7)), ((40, 10), (0, 3)), ((-60, 10), (3, 3))]
    points = np.array([7.0 * direction(*angles) for angles, _ in cases])
    projection = project(points, SMALL)
    assert projection.rows.tolist() == [pixel[0] for _, pixel in cases]
    assert projection.cols.tolist() == [pixel[1] for _, pixel in cases]
    np.testing.assert_allclose(projection.ranges, 7.0)


def test_a_pixel_keeps_its_nearest_point() -> None:
    ray = direction(-15, 100)
    points = np.array([9.0 * ray, 3.0 * ray, 6.0 * ray, 5.0 * direction(5, -10)])
    projection = project(points, SMALL)
    assert projection.pixel_point[2, 1] == 1
    assert projection.pixel_point[0, 4] == 3
    assert np.count_nonzero(projection.pixel_point >= 0) == 2
    assert projection.image_range[2, 1] == pytest.approx(3.0)
    assert np.isinf(projection.image_range[1, 1])


def test_range_image_is_normalised_by_the_models_statistics() -> None:
    section = dataclasses.replace(
        SMALL, mean_range=2.0, std_range=4.0, mean_x=1.0, std_x=2.0, mean_y=-1.0, std_y=0.5,
        mean_z=0.5, std_z=0.25, mean_remission=0.3, std_remission=0.1, remission_scale=0.01,
    )  # fmt: skip
    point = 6.0 * direction(-15, 100)
    points = np.array([point])
    projection = project(points, section)
    image = range_image(points, np.array([50.0]), projection, section)
    assert image.shape == (5, HEIGHT, WIDTH) and image.dtype == np.float32
    expected = [(6 - 2) / 4, (point[0] - 1) / 2, (point[1] + 1) / 0.5, (point[2] - 0.5) / 0.25,
                (0.5 - 0.3) / 0.1]  # fmt: skip
    np.testing.assert_allclose(image[:, 2, 1], expected, rtol=1e-5, atol=1e-6)
    image[:, 2, 1] = 0
    assert not image.any(), 'empty pixels must be 0 after normalisation'
    without = range_image(points, None, projection, section)
    assert without[4, 2, 1] == 0.0, 'no intensity: the mean remission'


# -- KNN back-projection ---------------------------------------------------------------
def reference_knn(classes, projection, knn, search, sigma, cutoff) -> np.ndarray:
    """Clean up point by point, written plainly with loops (the reference, small scenes)."""
    height, width = classes.shape
    weights = window_weights(search, sigma).reshape(search, search)
    image_range = projection.image_range
    num_classes = int(classes.max()) + 1
    out = []
    for i, (row, col) in enumerate(zip(projection.rows, projection.cols, strict=True)):
        candidates = []
        for a in range(search):
            for b in range(search):
                r, c = row + a - search // 2, (col + b - search // 2) % width
                if a == b == search // 2:
                    rng = projection.ranges[i]
                elif 0 <= r < height:
                    rng = image_range[r, c]
                else:
                    continue
                d = abs(rng - projection.ranges[i]) * weights[a, b]
                if np.isfinite(d):
                    candidates.append((d, classes[r, c]))
        candidates.sort(key=lambda item: item[0])
        counts = np.zeros(num_classes, int)
        for d, k in candidates[:knn]:
            if (cutoff <= 0 or d <= cutoff) and k > 0:
                counts[k] += 1
        out.append(int(counts.argmax()) if counts.max() > 0 else int(classes[row, col]))
    return np.array(out)


def test_knn_moves_an_occluded_point_to_its_surfaces_class() -> None:
    # A wall 10 m away fills the 3 lower rows of columns 1-7; a post 3 m away stands in front
    # of pixel (2, 4). The wall point behind the post takes the post's class alone, its
    # neighbours' (the wall's) with the KNN clean-up; the post keeps its own.
    section = dataclasses.replace(SMALL, mean_range=6.0, std_range=1.0)
    wall = [10.0 * direction(5 - 10 * row, 157.5 - 45 * col) for row in (1, 2, 3)
            for col in range(1, 8)]  # fmt: skip
    points = np.array([*wall, 3.0 * direction(-15, -22.5)])
    projection = project(points, section)
    behind = int(np.flatnonzero((projection.rows == 2) & (projection.cols == 4))[0])
    classes = np.where(projection.image_range > 6.0, 1, 2)
    classes[np.isinf(projection.image_range)] = 0
    alone = knn_clean_up(classes, projection, 0, 5, 1.0, 1.0)
    assert alone[behind] == 2
    for compiled in (False, True):
        cleaned = knn_clean_up(classes, projection, 5, 5, 1.0, 1.0, compiled=compiled)
        assert cleaned[behind] == 1 and cleaned[-1] == 2
        assert (cleaned[:-1] == 1).all()


@settings(max_examples=30, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**31 - 1),
    knn=st.integers(1, 9),
    search=st.sampled_from([3, 5]),
    cutoff=st.sampled_from([0.0, 0.5, 2.0]),
)
def test_knn_matches_the_plain_reference(seed: int, knn: int, search: int, cutoff: float) -> None:
    rng = np.random.default_rng(seed)
    count = 60
    pitch = rng.uniform(-35, 15, count)
    yaw = rng.uniform(-180, 180, count)
    distance = rng.uniform(1, 6, count)
    points = np.array([d * direction(p, y) for d, p, y in zip(distance, pitch, yaw, strict=True)])
    projection = project(points, SMALL)
    classes = rng.integers(0, 4, (HEIGHT, WIDTH))
    knn = min(knn, search * search)
    expected = reference_knn(classes, projection, knn, search, 1.0, cutoff)
    for compiled in (False, True):
        got = knn_clean_up(classes, projection, knn, search, 1.0, cutoff, compiled=compiled)
        np.testing.assert_array_equal(got, expected, err_msg=f'compiled={compiled}')


# -- the network end to end --------------------------------------------------------------
def segmenter(tmp_path: Path, weights=Z_WEIGHTS, argmax: bool = False, **section) -> OnnxSegmenter:
    model = linear_model(tmp_path / 'model.onnx', weights, HEIGHT, WIDTH, argmax=argmax)
    config = RegistrationConfig(
        threads=1, onnx_labels=dataclasses.replace(SMALL, model=str(model), **section)
    )
    return OnnxSegmenter.from_config(config)


def test_height_network_labels_every_point_with_the_default_class_map(tmp_path: Path) -> None:
    # mean_z 1, std_z 0.5: class 1 (raw 10, car) above 1.5 m, class 2 (raw 11) below 0.5 m,
    # class 0 (unlabeled) between. Each point alone in its pixel, no KNN.
    seg = segmenter(tmp_path, mean_z=1.0, std_z=0.5, knn=0)
    assert seg.providers == ['CPUExecutionProvider']
    points = np.array([[5.0, 0.0, 2.0], [0.0, 5.0, 0.2], [-5.0, 0.0, 1.0], [0.0, -5.0, -1.5]])
    raw = seg.labels(points, None)
    assert raw.dtype == np.int32 and raw.tolist() == [10, 11, 0, 11]
    # The model's statistics matter: with RangeNet++'s defaults (mean_z -1.04, std_z 0.86)
    # class 1 starts at -0.18 m, so 0.2 m and 1 m are class 1 too; -1.5 m is between.
    default = segmenter(tmp_path, knn=0)
    assert default.labels(points, None).tolist() == [10, 10, 10, 0]


def test_class_map_yaml_and_argmax_models(tmp_path: Path) -> None:
    class_map = tmp_path / 'data_cfg.yaml'
    class_map.write_text('name: test\nlearning_map_inv:\n  0: 0\n  1: 50\n  2: 40\n')
    seg = segmenter(tmp_path, argmax=True, mean_z=1.0, std_z=0.5, knn=0, class_map=str(class_map))
    points = np.array([[5.0, 0.0, 2.0], [0.0, 5.0, 0.2], [-5.0, 0.0, 1.0]])
    assert seg.labels(points, np.ones(3)).tolist() == [50, 40, 0]
    plain = tmp_path / 'plain.yaml'
    plain.write_text('1: 81\n')
    assert load_class_map(plain).tolist() == [0, 81]
    default = load_class_map()
    assert default.tolist()[:3] == [0, 10, 11] and default[19] == 81 and len(default) == 20


def test_labels_through_the_knn_and_non_finite_points(tmp_path: Path) -> None:
    # The occluded wall point of the KNN test, through the network (classes by range).
    wall = [10.0 * direction(5 - 10 * row, 157.5 - 45 * col) for row in (1, 2, 3)
            for col in range(1, 8)]  # fmt: skip
    points = np.array([*wall, 3.0 * direction(-15, -22.5), [np.nan, 0.0, 0.0]])
    seg = segmenter(tmp_path, RANGE_WEIGHTS, mean_range=6.0, std_range=1.0)
    raw = seg.labels(points, np.full(len(points), 0.2))
    assert (raw[:-2] == 10).all() and raw[-2] == 11 and raw[-1] == 0
    alone = segmenter(tmp_path, RANGE_WEIGHTS, mean_range=6.0, std_range=1.0, knn=0)
    assert (alone.labels(points, None) == 11).sum() == 2, 'without KNN the wall point is wrong'
    assert seg.labels(np.zeros((0, 3)), None).shape == (0,)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1))
def test_labels_do_not_depend_on_the_point_order(tmp_path_factory, seed: int) -> None:
    seg = segmenter(tmp_path_factory.mktemp('order'), RANGE_WEIGHTS, mean_range=5.0)
    rng = np.random.default_rng(seed)
    points = rng.uniform(-12, 12, (200, 3))
    points[:, 2] *= 0.2
    order = rng.permutation(len(points))
    np.testing.assert_array_equal(seg.labels(points, None)[order], seg.labels(points[order], None))


# -- configuration ------------------------------------------------------------------------
def test_config_rules(tmp_path: Path) -> None:
    errors = RegistrationConfig(label_source='onnx').errors()
    assert any('onnx_labels.model is not set' in e for e in errors)
    assert RegistrationConfig().errors() == [], 'only checked with label_source onnx'
    bad = dataclasses.replace(SMALL, model=str(tmp_path / 'missing.onnx'), fov_down=20.0,
                              knn_search=4, knn=17)  # fmt: skip
    text = ' '.join(bad.check())
    assert 'is not a file' in text and 'fov_down' in text and 'must be odd' in text
    assert 'exceeds' in text
    with pytest.raises(ConfigError, match='not set'):
        OnnxSegmenter.from_config(OnnxLabelsConfig())


def test_a_model_of_another_image_size_is_refused(tmp_path: Path) -> None:
    model = linear_model(tmp_path / 'wide.onnx', Z_WEIGHTS, HEIGHT, 2 * WIDTH)
    with pytest.raises(ConfigError, match=r'onnx_labels\.width'):
        OnnxSegmenter.from_config(dataclasses.replace(SMALL, model=str(model)))
    garbage = tmp_path / 'garbage.onnx'
    garbage.write_bytes(b'not a model')
    with pytest.raises(ConfigError, match=r'garbage\.onnx'):
        OnnxSegmenter.from_config(dataclasses.replace(SMALL, model=str(garbage)))


def test_cuda_is_refused_without_onnxruntime_gpu(tmp_path: Path) -> None:
    import onnxruntime

    if 'CUDAExecutionProvider' in onnxruntime.get_available_providers():
        pytest.skip('onnxruntime-gpu is installed here')
    with pytest.raises(ConfigError, match='onnxruntime-gpu'):
        segmenter(tmp_path, provider='cuda')


def test_label_source_onnx_gives_learning_ids(tmp_path: Path) -> None:
    from mlsemreg_ros.core.labeling.source import LabelSource

    model = linear_model(tmp_path / 'model.onnx', Z_WEIGHTS, HEIGHT, WIDTH)
    config = RegistrationConfig(
        label_source='onnx',
        onnx_labels=dataclasses.replace(SMALL, model=str(model), mean_z=1.0, std_z=0.5, knn=0),
    )
    assert config.errors() == []
    points = np.array([[5.0, 0.0, 2.0], [0.0, 5.0, 0.2], [-5.0, 0.0, 1.0]])
    labeled = LabelSource()(points, None, config)
    assert labeled.source == 'onnx' and labeled.labels.tolist() == [1, 2, 0]


def test_projection_of_a_range_projection_is_consistent() -> None:
    points = np.random.default_rng(3).normal(size=(500, 3)) * 8
    projection = project(points, SMALL)
    assert isinstance(projection, RangeProjection)
    filled = projection.pixel_point >= 0
    owners = projection.pixel_point[filled]
    rows, cols = np.nonzero(filled)
    assert (projection.rows[owners] == rows).all() and (projection.cols[owners] == cols).all()
    pixel = projection.rows * WIDTH + projection.cols
    nearest = np.full(HEIGHT * WIDTH, np.inf)
    np.minimum.at(nearest, pixel, projection.ranges)
    np.testing.assert_array_equal(projection.image_range.reshape(-1), nearest)


def test_the_odometry_labels_an_unlabeled_scan_with_the_network(tmp_path: Path) -> None:
    from mlsemreg_ros.core.odometry import Odometry

    model = linear_model(tmp_path / 'model.onnx', Z_WEIGHTS, HEIGHT, WIDTH)
    config = RegistrationConfig(
        label_source='onnx', onnx_labels=dataclasses.replace(SMALL, model=str(model))
    )
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-20, 20, (3000, 2)), rng.uniform(-2, 3, 3000)])
    step = Odometry(config=config).process(points, None, 1)
    assert step.prepared.input_stats['label_source'] == 'onnx'
    assert step.prepared.timings_ms['labeling_ms'] > 0


def test_the_odometry_hands_the_intensity_to_the_label_source(tmp_path: Path) -> None:
    from mlsemreg_ros.core.odometry import Odometry

    # Scores (0, m_n, -m_n): class 1 (raw 10) for remission above its mean, 2 below.
    weights = ([[0, 0, 0, 0, 0], [0, 0, 0, 0, 1], [0, 0, 0, 0, -1]], [0.0, 0.0, 0.0])
    model = linear_model(tmp_path / 'model.onnx', weights, HEIGHT, WIDTH)
    config = RegistrationConfig(
        label_source='onnx', onnx_labels=dataclasses.replace(SMALL, model=str(model), knn=0)
    )
    odometry = Odometry(config=config)
    seen = []
    source = odometry.label_source

    def recording(points, labels, cfg, intensity=None):
        labelled = source(points, labels, cfg, intensity)
        seen.append(labelled.labels)
        return labelled

    odometry.label_source = recording
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-20, 20, (3000, 2)), rng.uniform(-2, 3, 3000)])
    odometry.process(points, None, 1, intensity=np.full(3000, 0.9))
    assert (seen[-1] == 1).all(), 'bright points: class 1 (learning id 1, car)'
    odometry.process(points, None, 2, intensity=np.full(3000, 0.01))
    assert (seen[-1] == 2).all()
