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
"""Label noise, the label ceiling, the adaptive label model, confident landmarks."""

from mlsemreg_ros.core.config import ConfidenceConfig, VerificationConfig
from mlsemreg_ros.core.estimation.label_model import (
    cooccurrence,
    label_ceiling,
    label_refusal,
    LabelModel,
    self_agreement,
)
from mlsemreg_ros.core.estimation.verification import (
    dense_scores,
    label_compatibility,
    LabelCompatibility,
)
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.matching.landmarks import extract_landmarks
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.evaluation.label_noise import LabelNoise, LabelNoiseError
from noisy_labels import labeled_points_scan
import numpy as np
import pytest

LABELS = LabelMap.load()
ID = {n: LABELS.id_of(n) for n in ('road', 'sidewalk', 'building', 'vegetation', 'pole', 'car')}


def _scan(points: np.ndarray, labels: np.ndarray) -> PreparedScan:
    return labeled_points_scan(points, labels, LABELS.num_classes)


def _street(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Build a 0.3 m grid street: road, sidewalks, a building wall left, a hedge right, poles."""
    x = np.arange(-20.0, 20.0, 0.3)
    road = np.stack(np.meshgrid(x, np.arange(-4.0, 4.0, 0.3)), -1).reshape(-1, 2)
    walk = np.stack(
        np.meshgrid(x, np.r_[np.arange(-6.0, -4.0, 0.3), np.arange(4.0, 6.0, 0.3)]), -1
    )
    wall = np.stack(np.meshgrid(x, np.arange(0.0, 6.0, 0.3)), -1).reshape(-1, 2)
    pole_z = np.arange(0.0, 4.0, 0.3)
    poles = np.array([[px, 5.0, z] for px in (-15.0, -3.0, 9.0) for z in pole_z])
    points = np.vstack(
        [
            np.column_stack([road, np.zeros(len(road))]),
            np.column_stack([walk.reshape(-1, 2), np.zeros(walk.size // 2)]),
            np.column_stack([wall[:, 0], np.full(len(wall), -6.5), wall[:, 1]]),
            np.column_stack([wall[:, 0], np.full(len(wall), 6.5), wall[:, 1] / 3]),
            poles,
        ]
    )
    labels = np.concatenate(
        [
            np.full(len(road), ID['road']),
            np.full(walk.size // 2, ID['sidewalk']),
            np.full(len(wall), ID['building']),
            np.full(len(wall), ID['vegetation']),
            np.full(len(poles), ID['pole']),
        ]
    )
    return points + rng.normal(0.0, 0.02, points.shape), labels


def test_label_noise_specs_are_parsed_and_bad_ones_rejected():
    assert LabelNoise.parse('flip:0.2') == LabelNoise(flip=0.2)
    assert LabelNoise.parse('flip:0.1,confuse:0.3') == LabelNoise(0.1, 0.3)
    assert not LabelNoise.parse('none').active and str(LabelNoise(0.0, 0.3)) == 'confuse:0.3'
    for bad in ('flop:0.2', 'flip', 'flip:x', 'confuse:1.5'):
        with pytest.raises(LabelNoiseError):
            LabelNoise.parse(bad)


def test_flips_and_confusions_change_the_asked_share_of_the_asked_classes():
    rng = np.random.default_rng(0)
    ids = rng.choice([ID['road'], ID['building'], ID['car']], 40000).astype(np.int32)
    confused = LabelNoise(confuse=0.3).apply(ids, LABELS, np.random.default_rng(1))
    building = ids == ID['building']
    assert np.mean(confused[building] == ID['vegetation']) == pytest.approx(0.3, abs=0.02)
    assert np.mean(confused[ids == ID['road']] == ID['sidewalk']) == pytest.approx(0.3, abs=0.02)
    assert np.array_equal(confused[ids == ID['car']], ids[ids == ID['car']])  # not confused
    flipped = LabelNoise(flip=0.2).apply(ids, LABELS, np.random.default_rng(2))
    # a flip draws any of the 20 ids, its own one time in 20
    assert np.mean(flipped != ids) == pytest.approx(0.2 * 19 / 20, abs=0.01)
    raw = LABELS.to_raw(ids)
    noisy_raw = LabelNoise(flip=0.2).apply(raw, LABELS, np.random.default_rng(2))
    assert np.array_equal(LABELS.to_learning(noisy_raw, 'raw'), flipped)


def test_the_ceiling_follows_the_noise_so_the_relative_agreement_does_not():
    """Right pose: A / ceiling stays put as the flips grow; a 5 m slide stays below it."""
    rng = np.random.default_rng(3)
    points, labels = _street(rng)
    config = VerificationConfig()
    compat = label_compatibility(LABELS, config)
    slide = np.eye(4)
    slide[1, 3] = 2.0  # the hedge onto the sidewalk, sidewalk onto road
    relative = {}
    for flip in (0.0, 0.3):
        noise = LabelNoise(flip=flip)
        src = _scan(points, noise.apply(labels, LABELS, np.random.default_rng(4)))
        dst = _scan(points + rng.normal(0, 0.05, points.shape), labels)
        dst = _scan(dst.points, noise.apply(labels, LABELS, np.random.default_rng(5)))
        ceiling = label_ceiling(src, dst, compat, config)
        poses = np.stack([np.eye(4), slide])
        _, agreement = dense_scores(poses, src, dst.points_tree(), dst.labels, compat, config)
        relative[flip] = agreement / ceiling
        assert ceiling == pytest.approx(self_agreement(src, compat, config), abs=0.05)
    assert relative[0.3][0] == pytest.approx(relative[0.0][0], abs=0.08)
    assert relative[0.3][1] < 0.7 < relative[0.3][0]
    rule = ConfidenceConfig()
    assert label_refusal(0.45, 0.5, rule) == ''  # 0.9 of what these labels can give
    assert 'ceiling' in label_refusal(0.3, 0.5, rule)
    assert 'label_floor' in label_refusal(0.2, 0.22, rule)
    assert 'min_label_agreement' in label_refusal(0.45, 0.5, ConfidenceConfig(label_rule='fixed'))
    assert label_refusal(0.65, float('nan'), rule) == ''  # unknown ceiling: the fixed rule


def test_the_adaptive_model_learns_a_swapped_class_pair_on_a_stream():
    """Building seen as vegetation 40 % of the time: learned; road~car never."""
    rng = np.random.default_rng(6)
    points, labels = _street(rng)
    config = VerificationConfig(seed=0)
    fixed = label_compatibility(LABELS, config)
    model = LabelModel(fixed.compatible, min_count=50.0)
    b, v = ID['building'], ID['vegetation']
    before = None
    for _frame in range(12):
        src = _scan(points, labels)
        seen = np.where((labels == b) & (rng.random(len(labels)) < 0.4), v, labels)
        dst = _scan(points + rng.normal(0, 0.05, points.shape), seen)
        learned = LabelCompatibility(model.compatibility(), fixed.counted)
        _, agreement = dense_scores(
            np.eye(4)[None], src, dst.points_tree(), dst.labels, learned, config
        )
        before = agreement[0] if before is None else before
        model.update(cooccurrence(np.eye(4), src, dst, LABELS.num_classes, config))
    weights = model.compatibility()
    assert weights[b, v] > 0.5 and weights[v, b] == weights[b, v]
    assert weights[ID['road'], ID['car']] == 0.0 and weights[ID['road'], ID['sidewalk']] < 0.2
    assert model.confused_pairs(LABELS.names) == ['building~vegetation']
    assert agreement[0] > before + 0.05  # the confusion stopped counting as disagreement


def test_model_rejects_counts_of_the_wrong_shape():
    with pytest.raises(ValueError, match='co-occurrence'):
        LabelModel(np.eye(3)).update(np.ones((2, 2)))


def test_landmarks_come_only_from_confidently_labeled_points():
    """A pole keeps its landmark; pole labels scattered over a wall make none."""
    rng = np.random.default_rng(7)
    wall = np.column_stack(
        [
            rng.uniform(0, 20, 3000),
            np.full(3000, 5.0) + rng.normal(0, 0.05, 3000),
            rng.uniform(0, 6, 3000),
        ]
    )
    labels = np.full(3000, ID['building'])
    labels[rng.random(3000) < 0.03] = ID['pole']  # flips
    pole = np.column_stack([np.full(14, 30.0), np.zeros(14), np.linspace(0, 3.9, 14)])
    points = np.vstack([wall, pole])
    labels = np.r_[labels, np.full(14, ID['pole'])]
    plain = extract_landmarks(points, labels, np.array([ID['pole']]), 1.5, 3)
    assert any(c[0] < 21 for c in plain.centroids)  # the flips chain into false landmarks
    kept = extract_landmarks(points, labels, np.array([ID['pole']]), 1.5, 3, 0.2, 0.6)
    assert len(kept) == 1
    np.testing.assert_allclose(kept.centroids[0], [30.0, 0.0, 1.95], atol=1e-6)


@pytest.mark.slow
def test_the_odometry_teaches_the_adaptive_model_a_network_confusion_online():
    """A synthetic street drive whose 'network' sees 40 % of the building as vegetation."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from street_map import street_drive

    config = RegistrationConfig().replace(
        {'keypoints.count': 1000, 'confidence.label_model': 'adaptive'}
    )
    registration = Registration(config)
    odometry = Odometry(registration)
    rng = np.random.default_rng(8)
    b, v = ID['building'], ID['vegetation']
    accepted = 0
    for points, labels, _, stamp in street_drive(8, -20.0):
        labels = np.where((labels == b) & (rng.random(len(labels)) < 0.4), v, labels)
        accepted += odometry.process(points, labels, stamp).accepted
    model = registration.label_model
    assert accepted == 8 and model is not None and model.updates == 7
    assert 'building~vegetation' in model.confused_pairs(LABELS.names)
    assert registration._label_compatibility.compatible[b, v] > 0.5
    registration.config = config.replace({'confidence.min_overlap': 0.1})  # live tuning
    assert registration.label_model.updates == 7  # keeps what it learned
    registration.config = config.replace({'confidence.label_model': 'fixed'})
    assert registration.label_model is None
    assert not registration._label_compatibility.compatible[b, v]


def test_a_dev_pair_with_30_percent_confused_labels_is_accepted_at_its_pose_not_at_a_slide():
    """000007 with confusions: the fixed 0.6 rule refuses its right pose, the relative one not."""
    from dev_pairs import dev_pair_files
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import load_pair
    from mlsemreg_ros.evaluation.label_noise import scan_rng

    path = next(p for p in dev_pair_files() if p.stem == '000007')
    pair = load_pair(path)
    noise = LabelNoise(confuse=0.3)
    config = RegistrationConfig()
    registration = Registration(config)
    source, target = registration.prepare_scans(
        *(
            {
                'points': points,
                'labels': noise.apply(labels, LABELS, scan_rng(0, 4, scan)),
                'keypoints': keypoints,
                'descriptors': descriptors,
                'voxelize': False,
            }
            for scan, (points, labels, keypoints, descriptors) in enumerate(
                [
                    (pair.pts_src, pair.label_src, pair.kpts_src, pair.descriptors('gedi')[0]),
                    (pair.pts_dst, pair.label_dst, pair.kpts_dst, pair.descriptors('gedi')[1]),
                ]
            )
        )
    )
    result = registration.register(source, target)
    T = result.transform
    assert rotation_error_deg(T[:3, :3], pair.trans_gt[:3, :3]) < 5.0
    assert translation_error_m(T[:3, 3], pair.trans_gt[:3, 3]) < 0.6
    assert result.success, result.message
    # the labels' evidence at the pose (the pair may have been taken from its unlabeled
    # attempt, core/stages/label_quality.py, whose evidence has no labels)
    at_pose, _ = registration.judge(
        source, target, T, None, result.source_points, result.target_points
    )
    agreement, ceiling = at_pose.label_agreement, at_pose.label_ceiling
    assert agreement < 0.6 < agreement / ceiling  # fixed rule: refused
    assert label_refusal(agreement, ceiling, ConfidenceConfig(label_rule='fixed'))

    slide = pair.trans_gt.copy()
    slide[:3, 3] += pair.trans_gt[:3, :3] @ np.array([0.0, 2.0, 0.0])  # 2 m across the street
    evidence, refused = registration.judge(
        source, target, slide, None, result.source_points, result.target_points
    )
    assert refused  # the slide, judged as the pipeline judges its choice (relative rule)
    assert evidence.label_ceiling == pytest.approx(ceiling)
    assert label_refusal(evidence.label_agreement, ceiling, config.confidence)  # labels alone
    overlap, slid_agreement = dense_scores(
        slide[None],
        source,
        target.points_tree(),
        target.labels,
        label_compatibility(LABELS, config.verification),
        config.verification,
    )
    assert slid_agreement[0] == pytest.approx(evidence.label_agreement)
    assert overlap[0] == pytest.approx(evidence.overlap)
