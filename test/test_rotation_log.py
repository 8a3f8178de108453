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

"""SO(3)'s logarithm and exponential on plain floats: known answers and SciPy's to rounding."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from mlsemreg_ros.core.rigid import rotation_matrix, rotation_vector
import numpy as np
from scipy.spatial.transform import Rotation


def test_known_answers() -> None:
    """Identity, a quarter turn about z, a half turn about x."""
    assert np.array_equal(rotation_vector(np.eye(3)), np.zeros(3))
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.allclose(rotation_vector(quarter), [0.0, 0.0, np.pi / 2], atol=1e-15)
    assert np.allclose(rotation_matrix([0.0, 0.0, np.pi / 2]), quarter, atol=1e-15)
    half = np.diag([1.0, -1.0, -1.0])
    assert np.allclose(np.abs(rotation_vector(half)), [np.pi, 0.0, 0.0], atol=1e-15)
    assert np.allclose(rotation_matrix([np.pi, 0.0, 0.0]), half, atol=1e-15)


axes = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3)
angles = st.one_of(
    st.floats(0.0, np.pi),
    st.floats(1e-12, 1e-3),  # the small-angle series
    st.floats(np.pi - 1e-3, np.pi),  # near a half turn, where the sign flips
)


@settings(max_examples=300, deadline=None)
@given(axis=axes, angle=angles)
def test_equals_scipy(axis: tuple[float, float, float], angle: float) -> None:
    """The same rotation vector and matrix as SciPy's, to rounding (1e-14)."""
    rotvec = np.asarray(axis) / np.linalg.norm(axis) * angle
    matrix = Rotation.from_rotvec(rotvec).as_matrix()
    expected = Rotation.from_matrix(matrix).as_rotvec()
    assert np.allclose(rotation_vector(matrix), expected, atol=1e-14)
    assert np.allclose(rotation_matrix(rotvec), matrix, atol=1e-14)
    assert np.allclose(rotation_matrix(rotation_vector(matrix)), matrix, atol=1e-14)
