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
"""Labels as a noisy channel: the confusion estimate and the information rule (label_model)."""

from __future__ import annotations

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation import label_model
from mlsemreg_ros.core.estimation.config import ConfidenceConfig
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import BUILDING, synthetic_pair, VEGETATION
from noisy_labels import CONFIG, flipped, register_pair
import numpy as np
import pytest


@pytest.fixture(scope='module')
def scene():
    """Return the synthetic street pair."""
    return synthetic_pair(seed=0)


@pytest.fixture(scope='module')
def registration():
    """Return a registration with the test's config."""
    return Registration(RegistrationConfig().replace(CONFIG))


def prepared(registration, points, labels):
    """Return a lazily prepared scan (points, labels and the KD-tree are enough)."""
    return registration.prepare(points, labels, lazy=True)


def counts_at(registration, transform, source, target):
    """Return the dense label co-occurrence of ``transform`` (source label x target label)."""
    return label_model.cooccurrence(
        transform,
        source,
        target,
        registration.label_map.num_classes,
        registration.config.verification,
    )


def test_the_confusion_estimate_recovers_a_known_swap(scene, registration) -> None:
    """Source building <-> vegetation swapped: the true pose's confusion shows the swap."""
    swapped = np.array(scene.label_src, copy=True)
    swapped[scene.label_src == BUILDING] = VEGETATION
    swapped[scene.label_src == VEGETATION] = BUILDING
    source = prepared(registration, scene.pts_src, swapped)
    target = prepared(registration, scene.pts_dst, scene.label_dst)
    counted = registration.scoring().compatibility.counted
    at_truth = counts_at(registration, scene.trans_gt, source, target)
    matrix = label_model.confusion(at_truth, counted)
    building, vegetation = BUILDING, VEGETATION
    assert matrix[building, vegetation] > 0.7  # source "building" lies on target vegetation
    assert matrix[vegetation, building] > 0.7
    assert matrix[building, building] < 0.2
    np.testing.assert_allclose(matrix[matrix.sum(axis=1) > 0].sum(axis=1), 1.0)
    # the clean pair: the diagonal
    clean = prepared(registration, scene.pts_src, scene.label_src)
    at_truth = counts_at(registration, scene.trans_gt, clean, target)
    diagonal = label_model.confusion(at_truth, counted)
    assert diagonal[building, building] > 0.7 and diagonal[vegetation, vegetation] > 0.5


def test_information_is_agreement_beyond_chance() -> None:
    """Known answers: perfect agreement 1, independent labels 0, a swap below 0."""
    compatibility = type('C', (), {})()
    compatibility.counted = np.array([False, True, True])
    compatibility.compatible = np.eye(3, dtype=bool)
    assert label_model.information(np.diag([0.0, 5.0, 5.0]), compatibility) == pytest.approx(1.0)
    independent = np.array([[0, 0, 0], [0, 4.0, 4.0], [0, 1.0, 1.0]])
    assert label_model.information(independent, compatibility) == pytest.approx(0.0)
    swap = np.array([[0, 0, 0], [0, 0.0, 5.0], [0, 5.0, 0.0]])
    assert label_model.information(swap, compatibility) == pytest.approx(-1.0)
    assert np.isnan(label_model.information(np.zeros((3, 3)), compatibility))


def test_flips_shrink_a_pose_and_the_labels_alike(scene, registration) -> None:
    """30 % flips: the right pose keeps its share of the labels' information; a slide does not."""
    compatibility = registration.scoring().compatibility
    config = registration.config.verification
    slide = scene.trans_gt.copy()
    slide[1, 3] += 4.0  # across the street: facades on the sidewalk
    shares = {}
    for share in (0.0, 0.3):
        source = prepared(registration, scene.pts_src, flipped(scene.label_src, share, 1))
        target = prepared(registration, scene.pts_dst, flipped(scene.label_dst, share, 2))
        ceiling = label_model.information_ceiling(source, target, compatibility, config)
        right = label_model.information(
            counts_at(registration, scene.trans_gt, source, target), compatibility
        )
        wrong = label_model.information(
            counts_at(registration, slide, source, target), compatibility
        )
        shares[share] = (ceiling, right / ceiling, wrong / ceiling)
    assert shares[0.3][0] < 0.7 * shares[0.0][0]  # the flips halve what the labels say
    assert shares[0.3][1] == pytest.approx(shares[0.0][1], abs=0.2)  # relative: the same
    assert shares[0.3][1] > 0.6 and shares[0.0][1] > 0.6
    assert shares[0.3][2] < shares[0.3][1] - 0.2  # the slide agrees less beyond chance


def test_the_information_rule_judges_the_share_of_the_labels_information() -> None:
    config = ConfidenceConfig(label_rule='information', min_relative_information=0.4)
    assert label_model.label_refusal(0.3, 0.5, config, 0.2, 0.4) == ''
    assert 'min_relative_information' in label_model.label_refusal(0.6, 0.9, config, 0.1, 0.4)
    assert label_model.label_refusal(0.1, 0.5, config) == ''  # unknown: geometry decides


def test_thirty_percent_flips_are_weighed_not_dropped(scene) -> None:
    """30 % flips carry information: matched with labels, judged by the information rule."""
    registration = Registration(RegistrationConfig().replace(CONFIG))
    source, target = registration.prepare_scans(
        {'points': scene.pts_src, 'labels': flipped(scene.label_src, 0.3, 1)},
        {'points': scene.pts_dst, 'labels': flipped(scene.label_dst, 0.3, 2)},
    )
    result = registration.register(source, target)
    assert not result.diagnostics['labels_judged_unlabeled']
    assert result.diagnostics['label_weight'] < 0.75
    assert result.diagnostics['label_information'] > 0.1
    assert result.diagnostics['confidence_label_information'] > 0.0
    assert result.success
    error = np.linalg.norm(result.transform[:3, 3] - scene.trans_gt[:3, 3])
    assert error < 0.3


def permuted(labels: np.ndarray) -> np.ndarray:
    """Return ``labels`` with their classes shifted (road -> sidewalk -> building ...)."""
    classes = np.unique(labels[labels > 0])
    out = np.array(labels, copy=True)
    for old, new in zip(classes, np.roll(classes, 1), strict=True):
        out[labels == old] = new
    return out


def test_poorer_labels_take_the_unlabeled_pose_unless_they_contradict_it(scene) -> None:
    """Geometric-weight labels: the unlabeled pose is kept; labels that contradict it veto it."""
    # 2000 keypoints: the unlabeled pose has 80 inliers, above 3 x estimator.min_inliers
    strong = {'keypoints.count': 2000, 'estimator.min_inliers': 20}
    zeros = register_pair(
        scene, np.zeros_like(scene.label_src), np.zeros_like(scene.label_dst), **strong
    )
    kept = register_pair(
        scene, scene.label_src, scene.label_dst, label_source='geometric', **strong
    )
    assert kept.diagnostics['label_weight'] < 0.75  # geometric labels weigh half
    assert kept.diagnostics.get('labels_unlabeled_first')
    assert kept.diagnostics['labels_unlabeled_information'] > 0.6
    assert kept.success and zeros.success
    np.testing.assert_allclose(kept.estimate, zeros.estimate, atol=1e-9)  # the same pose
    vetoed = register_pair(
        scene, permuted(scene.label_src), scene.label_dst, label_source='geometric', **strong
    )
    assert not vetoed.diagnostics.get('labels_unlabeled_first')
    assert vetoed.diagnostics['labels_unlabeled_information'] < 0.3


class Refuse:
    """A stage that refuses the labelled path's pose (moved ``shift`` m along x first)."""

    name = 'refuse'

    def __init__(self, shift: float = 0.0) -> None:
        self.shift = shift

    def wanted(self, context) -> bool:
        return True

    def run(self, context) -> None:
        context.transform = context.transform.copy()
        context.transform[0, 3] += self.shift
        context.doubt('refused by the test')


def test_a_refused_labelled_path_falls_back_to_the_accepted_unlabeled_pose(scene) -> None:
    """Never worse, pair by pair: what no labels accept, poorer labels do not lose."""
    # the unlabeled pose has 80 inliers: accepted, but under 3 x 30, so not taken first
    weak = {'keypoints.count': 2000, 'estimator.min_inliers': 30}
    zeros = register_pair(
        scene, np.zeros_like(scene.label_src), np.zeros_like(scene.label_dst), **weak
    )
    assert zeros.success
    results = {}
    cases = (
        ('kept', scene.label_src, 0.0),
        ('vetoed', permuted(scene.label_src), 0.0),
        ('elsewhere', scene.label_src, 5.0),
    )
    for name, label_src, shift in cases:
        registration = Registration(
            RegistrationConfig().replace({**CONFIG, **weak, 'label_source': 'geometric'})
        )
        at = [stage.name for stage in registration.stages].index('unlabeled_fallback')
        registration.stages.insert(at, Refuse(shift))
        source, target = registration.prepare_scans(
            {'points': scene.pts_src, 'labels': label_src},
            {'points': scene.pts_dst, 'labels': scene.label_dst},
        )
        results[name] = registration.register(source, target)
    kept, vetoed = results['kept'], results['vetoed']
    assert not kept.diagnostics.get('labels_unlabeled_first')
    assert kept.diagnostics.get('labels_unlabeled_fallback')
    assert kept.success, kept.message
    np.testing.assert_allclose(kept.estimate, zeros.estimate, atol=1e-9)  # none's pose
    # labels that contradict the unlabeled pose keep their veto: the refusal stands, also
    # against the whole unlabeled registration run again (stage 10)
    assert not vetoed.diagnostics.get('labels_unlabeled_fallback')
    assert vetoed.diagnostics.get('labels_unlabeled_rerun_accepted')
    assert not vetoed.diagnostics.get('labels_unlabeled_rerun')
    assert not vetoed.success
    # a labelled path refused at another pose (5 m off): the two paths disagree, so the
    # quick attempt's pose is not taken; the pair is registered again as `none` registers
    # it (every stage) and takes that verdict: none's pose, accepted
    elsewhere = results['elsewhere']
    assert elsewhere.diagnostics['labels_unlabeled_agrees'] is False
    assert not elsewhere.diagnostics.get('labels_unlabeled_fallback')
    assert elsewhere.diagnostics.get('labels_unlabeled_rerun')
    assert elsewhere.success, elsewhere.message
    np.testing.assert_allclose(elsewhere.estimate, zeros.estimate, atol=1e-9)
