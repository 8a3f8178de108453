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
"""Never worse than no labels: the pair's labels judged and weighed (core/labeling/quality.py)."""

from __future__ import annotations

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.labeling import quality
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.results import Correspondences
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from noisy_labels import CONFIG, flipped, register_pair
import numpy as np
import pytest


@pytest.fixture(scope='module')
def scene():
    """Return the synthetic street pair."""
    return synthetic_pair(seed=0)


def test_labels_no_better_than_chance_are_judged_as_unlabeled(scene) -> None:
    """85 % flips: the pair registers exactly as with --labels none (the same pose, verdict)."""
    noisy = register_pair(
        scene, flipped(scene.label_src, 0.85, 1), flipped(scene.label_dst, 0.85, 2)
    )
    zeros = register_pair(scene, np.zeros_like(scene.label_src), np.zeros_like(scene.label_dst))
    assert noisy.diagnostics['labels_judged_unlabeled']
    assert noisy.diagnostics['label_weight'] == 0.0
    assert noisy.success == zeros.success
    np.testing.assert_allclose(noisy.transform, zeros.transform, atol=1e-9)
    assert noisy.num_inliers == zeros.num_inliers


def test_clean_labels_keep_their_full_weight(scene) -> None:
    result = register_pair(scene, scene.label_src, scene.label_dst)
    assert result.diagnostics['label_weight'] == pytest.approx(1.0)
    assert not result.diagnostics['labels_judged_unlabeled']
    assert result.success


def test_geometric_labels_are_weighed_by_their_trust(scene) -> None:
    source = LabelSource()
    config = RegistrationConfig().replace({**CONFIG, 'label_source': 'geometric'})
    src = source(scene.pts_src, None, config).labels
    dst = source(scene.pts_dst, None, config).labels
    result = register_pair(scene, src, dst, label_source='geometric')
    weight = result.diagnostics['label_weight']
    assert 0.0 < weight <= config.geometric_labels.trust
    assert result.diagnostics['label_pair_source'] == 'geometric'


def test_only_poorer_labels_widen_and_are_judged_as_unlabeled() -> None:
    assert quality.LabelQuality(0.5, 0.9, 0.9, 'geometric', False).widen
    assert not quality.LabelQuality(0.8, 0.95, 0.9, 'field', False).widen
    assert not quality.LabelQuality(0.0, 0.5, 0.05, 'field', True).widen


def test_poorer_labels_switch_to_the_information_rule_and_weigh_the_score() -> None:
    config = RegistrationConfig()
    weighed = quality.LabelQuality(0.4, 0.7, 0.3, 'field', False).config(config)
    assert weighed.confidence.label_rule == 'information'
    assert weighed.confidence.contradicting_objects == 0
    assert weighed.confidence.min_distinctive_ceiling == 1.0  # objects off below 0.5
    assert not weighed.levelling.enabled  # nor the ground of those labels
    assert weighed.verification.label_weight == pytest.approx(
        np.sqrt(0.4) * config.verification.label_weight
    )
    assert quality.LabelQuality(0.9, 0.95, 0.9, 'field', False).config(config) is config


def test_geometric_ground_gets_the_wider_tilt_check_whatever_the_weight() -> None:
    config = RegistrationConfig()
    wide = config.geometric_labels.tilt_tolerance
    assert wide > config.levelling.tolerance
    for weight in (0.5, 0.9):  # poorer and full weight
        judged = quality.LabelQuality(weight, 0.95, 0.9, 'geometric', False).config(config)
        assert judged.levelling.tolerance == wide
        assert judged.levelling.enabled
    # below OBJECTS_MIN_WEIGHT the ground levels nothing, geometric or not
    assert (
        not quality.LabelQuality(0.3, 0.7, 0.3, 'geometric', False)
        .config(config)
        .levelling.enabled
    )
    # the network's labels and unlabeled pairs keep levelling.tolerance
    field = quality.LabelQuality(0.5, 0.9, 0.9, 'field', False).config(config)
    assert field.levelling.tolerance == config.levelling.tolerance
    chance = quality.LabelQuality(0.0, 0.5, 0.05, 'geometric', True).config(config)
    assert chance is config
    # a larger levelling.tolerance wins
    strict = config.replace({'levelling.tolerance': wide + 3.0})
    judged = quality.LabelQuality(0.5, 0.95, 0.9, 'geometric', False).config(strict)
    assert judged.levelling.tolerance == wide + 3.0


def test_widened_correspondences_are_the_union_without_duplicates() -> None:
    semantic = Correspondences(np.array([0, 1, 2]), np.array([5, 6, 7]), np.ones(3, np.float32))
    plain = Correspondences(np.array([1, 3]), np.array([6, 8]), np.zeros(2, np.float32))
    union = quality.widened(semantic, plain)
    pairs = set(zip(union.source.tolist(), union.target.tolist(), strict=True))
    assert pairs == {(0, 5), (1, 6), (2, 7), (3, 8)}
