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
The ``onnx_labels`` section: the user's range-image segmentation network (docs/onnx_labels.md).

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py) and
used when ``label_source: onnx``. The defaults are RangeNet++'s SemanticKITTI settings
(Milioto et al., IROS 2019): an HDL-64E image of 64 x 2048 pixels from +3 to -25 deg, the
darknet53 arch_cfg's channel means and standard deviations, and its KNN clean-up
(k 5 in a 5 x 5 window, sigma 1, cutoff 1 m). SalsaNext and CENet use the same input.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mlsemreg_ros.core.settings import param

#: The providers ``onnx_labels.provider`` can name.
PROVIDERS = ('auto', 'cpu', 'cuda')


def _channel(kind: str, channel: str, default: float, low: float) -> float:
    """One channel's mean or standard deviation (the model's normalisation)."""
    what = 'Mean' if kind == 'mean' else 'Standard deviation'
    unit = '' if channel == 'remission' else 'm'
    return param(
        default,
        f"{what} of the input's {channel} channel, as the network was trained with "
        "(its arch_cfg's sensor img_means / img_stds).",
        unit=unit,
        low=low,
        high=1000.0,
    )


@dataclass
class OnnxLabelsConfig:
    """The range image, the normalisation, the KNN clean-up and the class map of the network."""

    model: str = param(
        '',
        'Path of the exported network (.onnx): input [1, 5, height, width] (range, x, y, '
        'z, remission), output [1, C, height, width] scores (or [1, height, width] class '
        'indices). No weights ship; docs/onnx_labels.md says how to export one.',
    )
    class_map: str = param(
        '',
        "YAML mapping the network's class indices to SemanticKITTI raw ids: a "
        'learning_map_inv (lidar-bonnetal data_cfg) or learning_to_raw mapping, or a '
        'plain index: id mapping. Empty: the SemanticKITTI learning ids (the 20 classes '
        'of config/labels/semantic_kitti.yaml).',
    )
    provider: str = param(
        'auto',
        'ONNX Runtime execution provider: auto (CUDA when onnxruntime-gpu is installed, '
        'else the CPU), cpu, or cuda (refused without onnxruntime-gpu).',
        choices=PROVIDERS,
    )
    height: int = param(64, 'Rows of the range image: the beams of the sensor.', low=1, high=1024)
    width: int = param(2048, 'Columns of the range image (360 deg of azimuth).', low=8, high=16384)
    fov_up: float = param(
        3.0,
        'Elevation of the top row of the range image.',
        unit='deg',
        low=-90.0,
        high=90.0,
    )
    fov_down: float = param(
        -25.0,
        'Elevation of the bottom row of the range image (must be below fov_up).',
        unit='deg',
        low=-90.0,
        high=90.0,
    )
    mean_range: float = _channel('mean', 'range', 12.12, -1000.0)
    mean_x: float = _channel('mean', 'x', 10.88, -1000.0)
    mean_y: float = _channel('mean', 'y', 0.23, -1000.0)
    mean_z: float = _channel('mean', 'z', -1.04, -1000.0)
    mean_remission: float = _channel('mean', 'remission', 0.21, -1000.0)
    std_range: float = _channel('std', 'range', 12.32, 1e-6)
    std_x: float = _channel('std', 'x', 11.47, 1e-6)
    std_y: float = _channel('std', 'y', 6.91, 1e-6)
    std_z: float = _channel('std', 'z', 0.86, 1e-6)
    std_remission: float = _channel('std', 'remission', 0.16, 1e-6)
    remission_scale: float = param(
        1.0,
        "Factor on the cloud's intensity before normalisation (1 for KITTI's remission in "
        "[0, 1]; 1/255 for a driver's 8-bit intensity). A cloud without intensity gets "
        'the mean remission.',
        low=0.0,
        high=1e6,
    )
    knn: int = param(
        5,
        "RangeNet++'s KNN clean-up: the neighbours whose labels vote for each point "
        "(0: each point takes its pixel's label).",
        low=0,
        high=121,
    )
    knn_search: int = param(
        5, 'KNN clean-up: the side of the search window in pixels (odd).', low=1, high=11
    )
    knn_sigma: float = param(
        1.0,
        'KNN clean-up: the sigma of the Gaussian that weighs range differences by pixel distance.',
        unit='px',
        low=1e-3,
        high=100.0,
    )
    knn_cutoff: float = param(
        1.0,
        'KNN clean-up: neighbours whose weighted range difference is above this do not vote '
        '(0: all vote).',
        unit='m',
        low=0.0,
        high=100.0,
    )

    def check(self) -> list[str]:
        """Cross-field rules, checked when ``label_source`` is ``onnx``."""
        errors = []
        if not self.model:
            errors.append('onnx_labels.model is not set (the path of the exported network)')
        elif not Path(self.model).expanduser().is_file():
            errors.append(f'onnx_labels.model {self.model!r} is not a file')
        if self.class_map and not Path(self.class_map).expanduser().is_file():
            errors.append(f'onnx_labels.class_map {self.class_map!r} is not a file')
        if self.fov_down >= self.fov_up:
            errors.append(
                f'onnx_labels.fov_down={self.fov_down:g} must be below '
                f'onnx_labels.fov_up={self.fov_up:g}'
            )
        if self.knn_search % 2 == 0:
            errors.append(f'onnx_labels.knn_search={self.knn_search} must be odd')
        if self.knn > self.knn_search**2:
            errors.append(
                f'onnx_labels.knn={self.knn} exceeds the {self.knn_search}x{self.knn_search} '
                'search window'
            )
        return errors
