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

"""A refused pose is refined with the downsampled source (``fine.refused_downsampled``)."""

from __future__ import annotations

from dev_pairs import dev_pair_files, register_dev_pair
from mlsemreg_ros.datasets.pairs import load_pair
import pytest


def _register(path, **flat):
    registration, source, result, metrics = register_dev_pair(load_pair(path), **flat)
    return registration.config, source, result, metrics


@pytest.mark.parametrize('downsampled', [True, False])
def test_a_refused_pose_is_refined_on_the_downsampled_source(downsampled):
    paths = [p for p in dev_pair_files() if p.stem == '000007']
    if not paths:
        pytest.skip('dev pair 000007 not present')
    # the one 20 m dev pair the confidence rule refuses (its labels disagree)
    config, source, result, metrics = _register(
        paths[0],
        **{
            'fine.refused_downsampled': downsampled,
            'bev_search.polish_fine': 0,  # the polishing's alignments: downsampled anyway
            'covisibility.refine_distance': 0.0,  # the covisible refinement's: full source
            'covisibility.accept_overlap': 0.0,  # refused: no near-miss check's clouds
        },
    )
    fine = config.fine
    pair_key, downsampled_key = (
        (0.0, fine.pair_num_neighbors),
        (
            fine.downsampling_resolution,
            fine.num_neighbors,
        ),
    )
    assert not result.success and result.alignment is not None
    # only the pair's fine alignment builds clouds here
    assert (downsampled_key in source.alignment_clouds) == downsampled
    assert (pair_key in source.alignment_clouds) == (not downsampled)
    assert metrics.success  # the refused pose is still the right one: RE 0.1-0.2 deg
    assert metrics.rotation_error_deg < 1.0 and metrics.translation_error_cm < 45.0
