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
Time the ONNX label source's steps on a 121,600-point 64-beam scan (docs/onnx_labels.md).

A benchmark, not a test: ``PYTHONPATH=$PWD .venv/bin/python test/bench_onnx_labels.py
[THREADS]``; ``MLSEMREG_KERNELS=numpy`` times the NumPy KNN. The network is a 1x1
convolution of 20 classes at 64 x 2048 (no real weights ship).
"""

from __future__ import annotations

from pathlib import Path
import sys
import tempfile
import time

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.labeling import onnx_segmentation as onnx_labels
from mlsemreg_ros.core.labeling.onnx_config import OnnxLabelsConfig
import numpy as np
from test_onnx_labels import linear_model


def synthetic_scan(rng: np.random.Generator) -> np.ndarray:
    """64 beams from +2 to -24.8 deg x 1900 azimuths, ranges 3-60 m: (121600, 3)."""
    pitch = np.radians(np.repeat(np.linspace(2.0, -24.8, 64), 1900))
    yaw = np.radians(np.tile(np.linspace(-180, 180, 1900, endpoint=False), 64))
    ranges = rng.uniform(3, 60, pitch.size)
    return ranges[:, None] * np.column_stack(
        [np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)]
    )


def main(threads: int = 1, runs: int = 7) -> None:
    """Print the median time of each step over ``runs`` runs."""
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as folder:
        weights = (rng.normal(size=(20, 5)).tolist(), [0.0] * 20)
        model = linear_model(Path(folder) / 'model.onnx', weights, 64, 2048)
        config = RegistrationConfig(
            threads=threads, onnx_labels=OnnxLabelsConfig(model=str(model))
        )
        segmenter = onnx_labels.OnnxSegmenter.from_config(config)
    points, intensity = synthetic_scan(rng), rng.uniform(0, 1, 121600)
    section = segmenter.section
    times: dict[str, list[float]] = {
        k: [] for k in ('projection', 'input', 'network', 'knn', 'labels')
    }
    for _ in range(runs):
        start = time.perf_counter()
        projection = onnx_labels.project(points, section)
        projected = time.perf_counter()
        image = onnx_labels.range_image(points, intensity, projection, section)
        built = time.perf_counter()
        classes = segmenter.predict(image)
        predicted = time.perf_counter()
        onnx_labels.knn_clean_up(
            classes,
            projection,
            section.knn,
            section.knn_search,
            section.knn_sigma,
            section.knn_cutoff,
        )
        cleaned = time.perf_counter()
        segmenter.labels(points, intensity)
        done = time.perf_counter()
        steps = (projected - start, built - projected, predicted - built, cleaned - predicted)
        for key, seconds in zip(times, (*steps, done - cleaned), strict=True):
            times[key].append(1e3 * seconds)
    print(
        f'{len(points)} points, {threads} thread(s):',
        ', '.join(f'{k} {np.median(v):.1f} ms' for k, v in times.items()),
    )


if __name__ == '__main__':
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
