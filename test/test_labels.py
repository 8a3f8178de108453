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
"""Label maps: raw and learning ids, instance bits, auto-detection, round trips."""

from mlsemreg_ros.core.config import ConfigError
from mlsemreg_ros.core.labels import LabelError, LabelMap
import numpy as np
import pytest

LABELS = LabelMap.load()


def test_names_and_ids():
    assert LABELS.num_classes == 20
    assert LABELS.id_of('traffic-sign') == 19 and LABELS.names[16] == 'trunk'
    with pytest.raises(ConfigError, match='known classes'):
        LABELS.id_of('lamp-post')


def test_raw_ids_with_instance_bits_map_to_learning_ids():
    raw = np.array([10, 40, 50, 252, 71, 80, 81, 18, 60, 99, 1], dtype=np.uint32)
    with_instance = raw | (np.array([7, 0, 0, 3, 12, 1, 2, 5, 0, 0, 0], np.uint32) << 16)
    expected = [1, 9, 13, 1, 16, 18, 19, 4, 9, 0, 0]
    np.testing.assert_array_equal(LABELS.to_learning(with_instance, 'raw'), expected)
    np.testing.assert_array_equal(LABELS.to_learning(with_instance, 'auto'), expected)


def test_learning_ids_pass_through_and_auto_detects_them():
    learning = np.arange(20, dtype=np.int64)
    np.testing.assert_array_equal(LABELS.to_learning(learning, 'auto'), learning)
    np.testing.assert_array_equal(LABELS.to_learning(learning.astype(np.float32)), learning)


@pytest.mark.parametrize('dtype', [np.uint8, np.int16, np.uint16, np.int32, np.uint32,
                                   np.int64, np.float32, np.float64])
def test_any_numeric_dtype_is_accepted(dtype):
    np.testing.assert_array_equal(LABELS.to_learning(np.array([9, 13], dtype=dtype)), [9, 13])


def test_signed_int32_raw_labels_with_large_instance_ids():
    raw = (np.array([40], np.uint32) | np.uint32(0xFFFF0000)).view(np.int32)
    assert raw[0] < 0
    np.testing.assert_array_equal(LABELS.to_learning(raw), [9])


def test_round_trip_learning_raw_learning():
    learning = np.arange(20)
    instance = np.arange(20) * 3
    raw = LABELS.to_raw(learning, instance)
    assert raw.dtype == np.uint32 and (raw >> 16).tolist() == instance.tolist()
    np.testing.assert_array_equal(LABELS.to_learning(raw, 'raw'), learning)


def test_invalid_labels_raise_clear_errors():
    with pytest.raises(LabelError, match='NaN'):
        LABELS.to_learning(np.array([1.0, np.nan]))
    with pytest.raises(LabelError, match='integral'):
        LABELS.to_learning(np.array([1.5]))
    with pytest.raises(LabelError, match='learning ids'):
        LABELS.to_learning(np.array([3, 25]), 'learning')
    with pytest.raises(LabelError, match='scheme'):
        LABELS.to_learning(np.array([3]), 'kitti')
