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
Whether the ONNX label source can run: its module (core/labeling/onnx_segmentation.py).

Apart from core/labeling/source.py so that the config's check can ask without an import
cycle (the source imports the label map, which imports the config).
"""

from __future__ import annotations

ONNX_MODULE = 'mlsemreg_ros.core.labeling.onnx_segmentation'


def onnx_unavailable() -> str:
    """Why ``label_source: onnx`` cannot run here ('' when it can)."""
    try:
        module = __import__(ONNX_MODULE, fromlist=['OnnxSegmenter'])
    except ImportError as error:
        return f'onnx label source not available ({error})'
    if not hasattr(module, 'OnnxSegmenter'):
        return f'onnx label source not available ({ONNX_MODULE} has no OnnxSegmenter)'
    return ''
