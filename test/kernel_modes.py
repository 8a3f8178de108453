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
The fixture that runs every test of a module with the compiled kernels and with NumPy.

A module takes it by importing it: ``from kernel_modes import kernel_mode  # noqa: F401``.
"""

from __future__ import annotations

from mlsemreg_ros.core.features import kernels
import pytest


@pytest.fixture(autouse=True, params=['numba', 'numpy'])
def kernel_mode(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Run every test with the compiled kernels and with the NumPy passes."""
    if request.param == 'numba' and not kernels.AVAILABLE:
        pytest.skip('numba is not installed')
    monkeypatch.setenv(kernels.ENV_SWITCH, request.param)
    return request.param
