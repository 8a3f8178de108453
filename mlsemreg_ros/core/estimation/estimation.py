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
Robust estimator factory: SC2-PCR (default) or the RANSAC baseline.

The pipeline imports ``estimate`` from here.
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation.config import EstimatorConfig
from mlsemreg_ros.core.results import EstimateResult
import numpy as np

__all__ = ['estimate']


def estimate(src: np.ndarray, dst: np.ndarray, config: EstimatorConfig) -> EstimateResult:
    """
    Estimate ``T_dst_src`` from ``(K, 3)`` correspondences with ``config.kind``.

    ``'sc2pcr'``: second-order spatial compatibility (Chen et al., CVPR 2022), its
    graph on at most ``config.graph_size`` correspondences;
    ``'ransac'``: Open3D's correspondence RANSAC.  The caller caps ``K`` at
    ``config.max_correspondences``.
    """
    if config.kind == 'sc2pcr':
        from mlsemreg_ros.core.estimation.sc2pcr import sc2pcr

        return sc2pcr(src, dst, config)
    if config.kind == 'ransac':
        from mlsemreg_ros.core.estimation.ransac import ransac

        return ransac(src, dst, config)
    raise ValueError(f"unknown estimator kind {config.kind!r}; expected 'sc2pcr' or 'ransac'")
