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
"""Label maps: raw and learning ids, instance bits, auto-detection by shares, counts."""

import warnings

from mlsemreg_ros.core.config import ConfigError
from mlsemreg_ros.core.matching.labels import (
    AUTO_RAW_MARGIN,
    LabelConversion,
    LabelError,
    LabelMap,
    MAX_OUT_OF_SCHEME_SHARE,
)
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


@pytest.mark.parametrize(
    'dtype', [np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.int64, np.float32, np.float64]
)
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
    with pytest.raises(LabelError, match=r'learning ids must lie in .0, 19. .*: 2 of 3 values'):
        LABELS.to_learning(np.array([3, 25, 70]), 'learning')
    with pytest.raises(LabelError, match=r'raw ids must be keys .* 3 of 3 .*label_scheme raw'):
        LABELS.to_learning(np.array([3, 5, 7]), 'raw')
    with pytest.raises(LabelError, match='scheme'):
        LABELS.to_learning(np.array([3]), 'kitti')
    for bad in (np.array([1 + 2j]), np.array(['car']), np.array([None])):
        with pytest.raises(LabelError, match='unsupported label dtype'):
            LABELS.to_learning(bad)


# -- input hygiene (issue 11) -------------------------------------------------------------
def _learning_scan(n: int = 1000, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 20, size=n)


def test_convert_reports_scheme_counts_and_shares():
    labels = np.array([9, 13, 25, 0])  # 25: neither a learning id nor a raw id
    out = LABELS.convert(labels)
    assert isinstance(out, LabelConversion) and len(out) == 4
    assert out.ids.dtype == np.int32 and out.ids.tolist() == [9, 13, 0, 0]
    assert (out.scheme, out.requested, out.out_of_scheme) == ('learning', 'auto', 1)
    # Shares over the non-zero values: 9, 13 learning; 13 raw (bus).
    assert out.learning_share == pytest.approx(2 / 3) and out.raw_share == pytest.approx(1 / 3)
    assert type(out.raw_share) is float and type(out.learning_share) is float
    np.testing.assert_array_equal(LABELS.to_learning(labels), out.ids)
    assert LABELS.detect_scheme(labels) == out.scheme


def test_one_value_above_19_no_longer_flips_a_learning_scan():
    labels = _learning_scan()
    labels[0] = 20  # a raw id (other-vehicle), not a learning id
    out = LABELS.convert(labels)
    assert out.scheme == 'learning' and out.out_of_scheme == 1
    np.testing.assert_array_equal(out.ids[1:], labels[1:])
    assert out.ids[0] == 0


def test_auto_margin_on_a_scan_of_ambiguous_ids():
    # Car 1, parking 10, sidewalk 11, building 13, vegetation 15, trunk 16, pole 18 are raw
    # ids too: a learning scan of only these is the hardest case for auto.
    ambiguous = np.array([1, 10, 11, 13, 15, 16, 18])
    rng = np.random.default_rng(1)
    base = rng.choice(ambiguous, size=1000)
    assert AUTO_RAW_MARGIN == 0.25
    for corrupted, expected in ((240, 'learning'), (260, 'raw')):
        labels = base.copy()
        labels[:corrupted] = 40  # road as a raw id: valid raw, not learning
        out = LABELS.convert(labels)
        assert out.scheme == expected, corrupted
        assert out.raw_share - out.learning_share == pytest.approx(corrupted / 1000)
    assert LABELS.convert(labels, 'learning').out_of_scheme == 260


def test_raw_scans_are_detected_by_share_even_with_mostly_unlabeled_points():
    rng = np.random.default_rng(2)
    learning = _learning_scan(2000, seed=3)
    raw = LABELS.to_raw(learning, rng.integers(0, 50, size=2000))
    out = LABELS.convert(raw)
    assert out.scheme == 'raw' and out.out_of_scheme == 0
    np.testing.assert_array_equal(out.ids, learning)
    # A camera-limited labeler: 80 % unlabeled (0 in both schemes), 20 % road and building.
    camera = np.zeros(1000, np.uint32)
    camera[:200] = rng.choice([40, 50], size=200)
    out = LABELS.convert(camera)
    assert out.scheme == 'raw' and out.raw_share == 1.0
    assert set(out.ids[:200].tolist()) == {9, 13} and not out.ids[200:].any()
    # A few corrupted values in a raw scan are counted, not fatal.
    raw[:7] = 12  # a learning id, not a raw id
    raw[7:10] = 1234  # not in the table
    out = LABELS.convert(raw)
    assert out.scheme == 'raw' and out.out_of_scheme == 10 and not out.ids[:10].any()


def test_all_zero_and_empty_scans_read_as_learning():
    for labels in (np.zeros(10, np.uint32), np.zeros(0, np.int64)):
        out = LABELS.convert(labels)
        assert out.scheme == 'learning' and out.out_of_scheme == 0
        assert out.ids.shape == labels.shape and not out.ids.any()
        assert (out.raw_share, out.learning_share) == (0.0, 0.0)


def test_int32_minimum_is_a_raw_label_with_instance_bits():
    # Issue 11: int32 -2**31 = 0x80000000 (instance 0x8000, class 0) was rejected.
    low = np.array([-(2**31)], np.int32)
    np.testing.assert_array_equal(LABELS.to_learning(low), [0])
    raw = LABELS.to_raw(np.array([9, 13, 15, 1]), np.array([0x8000, 3, 0xFFFF, 0x7FFF]))
    signed = np.concatenate([raw, [0x80000000]]).astype(np.uint32).view(np.int32)
    assert signed.min() == -(2**31)
    out = LABELS.convert(signed)
    assert out.scheme == 'raw' and out.out_of_scheme == 0
    np.testing.assert_array_equal(out.ids, [9, 13, 15, 1, 0])
    # The same bits as int64 (what the PointCloud2 decoder returns for an int32 field).
    np.testing.assert_array_equal(LABELS.to_learning(signed.astype(np.int64)), out.ids)


def test_narrow_signed_labels_are_sign_extended_to_32_bits():
    # int8/int16 -1 reads as 0xFFFFFFFF: a valid id in no scheme (never moving-motorcyclist
    # 255 nor class 0xFFFF), so it becomes unlabeled and is counted.
    for dtype in (np.int8, np.int16):
        labels = np.array([9, 13, -1, 17], dtype)
        out = LABELS.convert(labels)
        assert out.scheme == 'learning' and out.out_of_scheme == 1
        assert out.ids.tolist() == [9, 13, 0, 17]
        assert LABELS.convert(labels, 'raw', max_out_of_scheme=1.0).out_of_scheme == 3
    np.testing.assert_array_equal(LABELS.to_learning(np.array([40, 70, 81], np.int8)), [9, 15, 19])
    np.testing.assert_array_equal(LABELS.to_learning(np.array([252, 40], np.uint16)), [1, 9])


def test_values_beyond_32_bits_are_in_no_scheme():
    # 2**32 + 40 is not road: the value does not fit 32 bits.
    for labels in (
        np.array([2**32 + 40, 40, 50, 70], np.int64),
        np.array([2**63 + 40, 40, 50, 70], np.uint64),
        np.array([1e30, 40.0, 50.0, 70.0]),
        np.array([-(2.0**31) - 1, 40.0, 50.0, 70.0]),
    ):
        with warnings.catch_warnings():
            warnings.simplefilter('error')
            out = LABELS.convert(labels)
        assert out.scheme == 'raw' and out.out_of_scheme == 1, labels.dtype
        assert out.ids.tolist() == [0, 9, 13, 15]
    np.testing.assert_array_equal(LABELS.to_learning(np.array([-1, 9, 13], np.int64)), [0, 9, 13])


def test_float_raw_labels_with_instance_bits():
    raw = LABELS.to_raw(np.array([9, 16, 18]), np.array([0, 4, 900])).astype(np.float64)
    out = LABELS.convert(raw)
    assert out.scheme == 'raw' and out.ids.tolist() == [9, 16, 18]
    assert LABELS.to_learning(np.array([True, False, True])).tolist() == [1, 0, 1]


def test_out_of_scheme_limit():
    labels = np.array([9, 13, 50, 70])  # half not learning ids
    assert MAX_OUT_OF_SCHEME_SHARE == 0.5
    assert LABELS.convert(labels, 'learning').out_of_scheme == 2
    labels[1] = 80
    with pytest.raises(LabelError, match=r'3 of 4 values .75.0 %. are not, more than the 50 %'):
        LABELS.convert(labels, 'learning')
    out = LABELS.convert(labels, 'learning', max_out_of_scheme=1.0)
    assert out.out_of_scheme == 3 and out.ids.tolist() == [9, 0, 0, 0]
    # auto picks raw here (3 raw-only values of 4), so the same labels are fine.
    assert LABELS.convert(labels).scheme == 'raw'
    with pytest.raises(LabelError, match='auto read the scan as learning ids'):
        LABELS.convert(np.full(10, 300))  # neither scheme: garbage


def test_explicit_raw_scheme_counts_ids_missing_from_the_table():
    labels = np.array([40, 50, 0, 1, 2, 70 | (5 << 16)], np.uint32)  # 2: no raw id
    out = LABELS.convert(labels, 'raw')
    assert out.scheme == 'raw' and out.out_of_scheme == 1
    assert out.ids.tolist() == [9, 13, 0, 0, 0, 15]
    # Learning ids do not carry instance bits.
    out = LABELS.convert(np.array([9, 9 | (1 << 16), 13]), 'learning')
    assert out.out_of_scheme == 1 and out.ids.tolist() == [9, 0, 13]
