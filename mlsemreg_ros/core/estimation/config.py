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
The ``estimator``, ``verification``, ``bev_search`` and ``confidence`` sections.

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py),
which re-exports them; fields are :func:`~mlsemreg_ros.core.settings.param` declarations.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import ConfigError, param


def class_rule_names(rule: str) -> list[str]:
    """Return the class names of a ``class~class[~class...]`` rule, stripped."""
    return [name.strip() for name in rule.split('~')]


def _check_class_rules(
    key: str, rules: list[str], min_names: int, form: str, example: str
) -> None:
    """Raise ConfigError for a rule that is not ``min_names`` or more class names, ``~``-joined."""
    for rule in rules:
        names = class_rule_names(rule)
        if len(names) < min_names or not all(names):
            raise ConfigError(f'{key}: {rule!r} is not of the form {form} (e.g. {example!r})')


@dataclass
class EstimatorConfig:
    """Robust rigid transform estimation from correspondences."""

    kind: str = param(
        'sc2pcr',
        'sc2pcr: second-order spatial compatibility (Chen et al. 2022); ransac: '
        "Open3D's correspondence RANSAC (baseline).",
        choices=('sc2pcr', 'ransac'),
    )
    inlier_threshold: float = param(
        0.6,
        'Residual below which a correspondence is an inlier (hypothesis selection, diagnostics).',
        unit='m',
        low=0.01,
        high=10.0,
    )
    compatibility_threshold: float = param(
        0.6,
        'SC2-PCR d_thr: length-consistency threshold of the compatibility measures.',
        unit='m',
        low=0.01,
        high=10.0,
    )
    seed_ratio: float = param(
        0.5,
        'Maximum number of SC2-PCR seeds as a share of the graph correspondences.',
        low=0.001,
        high=1.0,
    )
    nms_radius: float = param(
        0.1, 'Non-maximum suppression radius for seed selection.', unit='m', low=0.0, high=10.0
    )
    k1: int = param(30, 'First-stage consensus set size per seed.', low=3, high=1000)
    k2: int = param(20, 'Second-stage consensus set size per seed.', low=3, high=1000)
    power_iterations: int = param(
        10, 'Power iterations for the leading eigenvector.', low=1, high=1000
    )
    second_order_budget: float = param(
        50.0,
        'Work budget of the SC2 stage (cost-model ms, about CPU ms on 2 cores): when '
        'seed_ratio x K seeds would exceed it, only the best-scored seeds that fit are kept '
        '(at least 64); 0 disables the budget.',
        unit='ms',
        low=0.0,
        high=1e6,
    )
    graph_size: int = param(
        500,
        'SC2-PCR builds its compatibility graph (seeds, consensus sets, hypotheses) on '
        'a seeded random subset of at most this many correspondences; every hypothesis is '
        'still scored, and the best refined, on all of them. Cost grows with its square '
        '(0: no limit).',
        low=0,
        high=100000,
    )
    graph_retry_inliers: int = param(
        50,
        'When the graph was sampled (estimator.graph_size) and its best hypothesis has '
        'fewer inliers than this on all correspondences, SC2-PCR runs again on the full '
        'graph: inlier ratios near 1 % leave too few inliers in the sample (0: never).',
        low=0,
        high=100000,
    )
    max_correspondences: int = param(
        10000,
        'Cap on correspondences fed to the estimator; the best ranked '
        '(smallest descriptor distance) are kept.',
        low=10,
        high=100000,
    )
    refine_threshold: float = param(
        1.2,
        'Inlier threshold of the reweighted least-squares refinement.',
        unit='m',
        low=0.01,
        high=20.0,
    )
    refine_iterations: int = param(
        20, 'Maximum reweighted least-squares refinement iterations.', low=0, high=1000
    )
    ransac_iterations: int = param(
        1000000, 'RANSAC maximum iterations (ransac estimator only).', low=1, high=100000000
    )
    ransac_confidence: float = param(
        0.999, 'RANSAC confidence (ransac estimator only).', low=0.0, high=1.0
    )
    min_inliers: int = param(
        40,
        'A registration with fewer inliers is reported as failed. Scans that do not '
        'overlap at all still give 12-49 by chance (2000 keypoints, dev-pair chain); see '
        'also confidence.*.',
        low=3,
        high=100000,
    )


@dataclass
class VerificationConfig:
    """
    Hypothesis verification on the dense labeled scans, after the estimator.

    The estimator's best distinct hypotheses are scored on the voxelized scans:
    ``score = overlap ** overlap_weight * label_agreement ** label_weight``
    (core/estimation/verification.py).
    """

    enabled: bool = param(
        True,
        'Verify the best distinct hypotheses of the estimator on the dense labeled scans '
        '(overlap and label agreement); false keeps the choice of the estimator (most inliers).',
    )
    hypotheses: int = param(
        5,
        'Hypotheses verified: the choice of the estimator and up to this many minus one other '
        'distinct ones, by descending inlier count (SC2-PCR: one per seed).',
        low=1,
        high=256,
    )
    distinct_rotation: float = param(
        5.0,
        'Two hypotheses are the same pose when they differ by at most this rotation and '
        'at most verification.distinct_translation (the success bounds).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    distinct_translation: float = param(
        0.6,
        'Translation bound of the same-pose test (see verification.distinct_rotation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    sample_points: int = param(
        2000,
        'Source scan points (seeded random subset) scored per hypothesis.',
        low=10,
        high=1000000,
    )
    overlap_distance: float = param(
        0.6,
        'A sampled source point overlaps when a target scan point lies within this '
        'distance of it under the hypothesis.',
        unit='m',
        low=0.01,
        high=10.0,
    )
    range_exponent: float = param(
        2.0,
        'Each sampled source point counts with the weight range^this (distance from the '
        'source sensor) in the overlap and the label agreement. A LiDAR samples a surface at '
        'range r with a density ~1/r^2: 2 makes both shares of the seen surface, not of the '
        'points, so the dense ground around the sensor cannot decide; 0: equal weights.',
        low=0.0,
        high=4.0,
    )
    overlap_weight: float = param(
        1.0, 'Exponent of the overlap fraction in the combined score.', low=0.0, high=10.0
    )
    label_weight: float = param(
        1.0,
        'Exponent of the label agreement in the combined score (0: geometry only).',
        low=0.0,
        high=10.0,
    )
    min_gain: float = param(
        0.05,
        'Another hypothesis replaces the choice of the estimator only when its score is '
        'higher by more than this share (0.05 = 5 %).',
        low=0.0,
        high=10.0,
    )
    compatible_classes: list[str] = param(
        [
            'vegetation~terrain',
            'vegetation~trunk',
            'road~parking',
            'building~fence',
            'pole~traffic-sign',
        ],
        'Label pairs (or groups, a~b~c) that count as agreeing besides equal labels '
        '(class names of the label map).',
    )
    ignored_classes: list[str] = param(
        ['unlabeled'],
        'Classes left out of the label agreement (their points still count for the overlap).',
    )
    seed: int = param(0, 'Seed of the source point sample.', low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        """Reject a compatibility rule that is not ``class~class[~class...]``."""
        _check_class_rules(
            'verification.compatible_classes',
            self.compatible_classes,
            2,
            "'class~class'",
            'vegetation~terrain',
        )


@dataclass
class BevSearchConfig:
    """
    Semantic bird's-eye-view search when the estimator's choice is refused (beyond the paper).

    The scans' static structure is correlated as BEV occupancy grids over every yaw and
    translation (FFT); the best peaks are refined on the correspondences and verified on
    the dense scans like the estimator's hypotheses (core/estimation/bev_search.py). Assumes z-up
    sensor frames and a mostly yaw motion between the scans (a ground vehicle).
    """

    enabled: bool = param(
        True,
        "Search the scans when confidence.* refuses the estimator's (verified) choice or "
        'accepts it on weak evidence (bev_search.weak_inliers); a searched pose replaces '
        'it when it scores higher on the dense scans. Needs verification.enabled. Costs '
        '~0.15 s, only on such registrations.',
    )
    weak_inliers: int = param(
        0,
        'Also search when the pose is accepted on fewer sparse inliers than this (0: only '
        'refused poses). On repetitive streets a slide along the street can pass every '
        'threshold with 40-100 inliers of plain FPFH matches (semantic.enabled=false): 100 '
        'catches most of them there, but ML-SemReg at 2000 keypoints has as few on right '
        "poses, and the search then runs on a quarter of the node's global registrations.",
        low=0,
        high=100000,
    )
    classes: list[str] = param(
        ['building~fence', 'vegetation~trunk', 'pole~traffic-sign'],
        'One BEV channel per entry: class names joined by ~ (static structure; '
        'the ground is everywhere and would favour no motion).',
    )
    cell_size: float = param(1.0, 'BEV cell size.', unit='m', low=0.1, high=10.0)
    radius: float = param(
        50.0,
        'Source points farther than this (x or y) from the sensor are left out.',
        unit='m',
        low=1.0,
        high=500.0,
    )
    max_translation: float = param(
        65.0,
        'Largest translation (x and y) searched (the composed dev pairs 60 m apart need 62 m).',
        unit='m',
        low=0.0,
        high=500.0,
    )
    yaw_step: float = param(
        2.0, 'Yaw step of the search over 360 deg.', unit='deg', low=0.1, high=90.0
    )
    peaks_per_yaw: int = param(3, 'Best local correlation maxima kept per yaw.', low=1, high=100)
    coarse_factor: int = param(
        3,
        'Coarse to fine: every coarse_factor x yaw_step is searched first, then the steps '
        'in between only around the bev_search.coarse_yaws best coarse yaws (1: every '
        'yaw_step; odd factors leave no step out).',
        low=1,
        high=30,
    )
    coarse_yaws: int = param(
        12,
        'Coarse yaws (by their best peak) searched again at yaw_step around them. On the '
        'dev pairs the yaw nearest the truth ranked at most 6th of 60 coarse yaws.',
        low=1,
        high=3600,
    )
    hypotheses: int = param(
        64,
        'Peaks (after suppression) refined and verified on the dense scans.',
        low=1,
        high=1024,
    )
    nms_rotation: float = param(
        4.0,
        'A peak within this yaw and bev_search.nms_translation of a better one is dropped.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    nms_translation: float = param(
        2.0, 'Translation bound of the peak suppression.', unit='m', low=0.0, high=100.0
    )
    guided_peaks: int = param(
        3,
        'When the best pose is still refused after the search: the keypoints are matched '
        'again around this many best searched poses (only within bev_search.guided_radius '
        'of where the pose puts them, compatible labels), and the estimator runs again on '
        'each set (core/estimation/guided.py; 0: off). 2 would cost a third less with the '
        'same verdicts on the ten pair sets, but loses solid-state scans (docs/hard_pairs.md, '
        'eighth round).',
        low=0,
        high=64,
    )
    full_graph: bool = param(
        False,
        'When the best pose is still refused after the guided re-matching and the estimator '
        'built its graph on a sample (estimator.graph_size): SC2-PCR again on every '
        'correspondence, verified (a 60 m dev pair keeps 5 of its 79 true correspondences '
        'in the sample). Off: since the far search it has given no accepted pose on the dev '
        'pairs, and the same verdicts without it (docs/hard_pairs.md, session 14).',
    )
    polish_candidates: int = param(
        16,
        'When the best pose is still refused after the search: this many best distinct '
        'candidates (by score), and every candidate lining up '
        'confidence.min_distinctive_objects, are polished by point-to-point ICP on the dense '
        'scans and scored again (core/estimation/polish.py; 0: off).',
        low=0,
        high=1024,
    )
    polish_fine: int = param(
        1,
        'After the polishing, this many best distinct candidates (polished or not) also get '
        "the pair's fine alignment (fine.pair_method, 6-DoF) and are scored again (0: none). "
        '1 instead of 2: the same verdicts on the ten pair sets, one GICP less '
        '(docs/hard_pairs.md, eighth round).',
        low=0,
        high=64,
    )
    polish_points: int = param(
        1000,
        'Source scan points (seeded random subset) matched in the polishing ICP.',
        low=10,
        high=100000,
    )
    polish_iterations: int = param(
        8, 'ICP steps of the polishing (bev_search.polish_candidates).', low=1, high=100
    )
    polish_radius: float = param(
        2.0,
        'Matching radius of the first polishing step; it shrinks to '
        'verification.overlap_distance over the first half of the steps.',
        unit='m',
        low=0.1,
        high=20.0,
    )
    guided_radius: float = param(
        3.0,
        'Guided re-matching: a source keypoint is matched only among the target keypoints '
        'within this distance of where the searched pose puts it (3 m: one more FPFH pair of '
        'the 40 m dev pairs than 2 m, the same GEDI pairs).',
        unit='m',
        low=0.1,
        high=20.0,
    )

    def __post_init__(self) -> None:
        """Reject an empty channel list or an empty class name."""
        if not self.classes:
            raise ConfigError('bev_search.classes: give at least one channel, e.g. building~fence')
        _check_class_rules(
            'bev_search.classes', self.classes, 1, "'class' or 'class~class'", 'building~fence'
        )


@dataclass
class ConfidenceConfig:
    """
    When a registration counts as successful (core/estimation/confidence.py), besides min_inliers.

    The dense scores are those of hypothesis verification for the chosen pose (overlap of
    the seen surface within verification.overlap_distance, label agreement of it).
    """

    min_inlier_ratio: float = param(
        0.005,
        'Smallest share of the correspondences that are inliers of the chosen pose '
        '(measured: right registrations >= 0.0074, with 20 % of the labels randomized).',
        low=0.0,
        high=1.0,
    )
    min_overlap: float = param(
        0.15,
        "Smallest share of the source scan's seen surface that lies on the target scan "
        'under the chosen pose (measured: right registrations >= 0.196).',
        low=0.0,
        high=1.0,
    )
    min_label_agreement: float = param(
        0.6,
        'Smallest share of the overlapping labeled points whose labels agree (or are '
        'compatible, verification.compatible_classes). Measured: right registrations >= '
        '0.60 (0.71 with the network labels as they are), wrong ones with >= 40 inliers '
        '<= 0.55.',
        low=0.0,
        high=1.0,
    )
    max_tilt: float = param(
        30.0,
        'Largest turn of the up (z) axis between the two scans: a ground vehicle does '
        'not roll over between two scans, but a mirrored or degenerate scene fits best '
        'upside down (180 disables the check).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    ambiguity_margin: float = param(
        0.3,
        'A rival pose (another candidate, the zero motion, or the chosen pose slid by '
        'confidence.slide_distance) whose verification score reaches (1 - this) x the '
        "chosen pose's makes the registration ambiguous, unless the distinctive structure "
        'decides (docs/hard_pairs.md). 0: only rivals scoring as high; 1: every '
        'rival counts.',
        low=0.0,
        high=1.0,
    )
    rival_translation: float = param(
        3.0,
        'A candidate is a rival when it differs from the chosen pose by more than this '
        'translation (or more than confidence.rival_rotation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    rival_rotation: float = param(
        10.0, 'Rotation bound of the rival test.', unit='deg', low=0.0, high=180.0
    )
    slide_distance: float = param(
        5.0,
        'The chosen pose slid by this along 8 horizontal directions is a rival too (a '
        'straight street lines up road, curbs and facades at any slide; 0: no slides).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    distinctive_classes: list[str] = param(
        ['pole', 'traffic-sign', 'trunk'],
        'Classes that pin a place down (not ground, not facades): the share of the source '
        'points of these classes that lie on target points of these classes decides '
        'between close rivals.',
    )
    min_distinctive_objects: int = param(
        2,
        'Distinctive source objects (connected points of confidence.distinctive_classes, '
        'e.g. one pole) that the chosen pose must line up with distinctive target points '
        '(within verification.overlap_distance) to decide between close rivals.',
        low=0,
        high=1000,
    )
    min_distinctive_fraction: float = param(
        0.5,
        'Share of the distinctive source objects in the target view (within 1 m of a target '
        'point) that the chosen pose must line up to decide between close rivals: a slide '
        'puts poles beside the target poles (dev pairs: <= 0.2 at the zero motion, >= 0.5 at '
        'the truth).',
        low=0.0,
        high=1.0,
    )
    contradicting_objects: int = param(
        3,
        'A pose that puts at least this many distinctive source objects in the target view '
        '(within 1 m of a target point) and lines up fewer than '
        'confidence.contradicted_fraction of them is refused (0: off).',
        low=0,
        high=1000,
    )
    contradicted_fraction: float = param(
        0.25,
        'See confidence.contradicting_objects. Dev pairs: right poses with 3 or more objects '
        'in view line up >= 0.5 of them (one 40 m pair: 0 of 3), zero-motion slides <= 0.2; '
        'a plain-FPFH slide of a simulated street: 1 of 18.',
        low=0.0,
        high=1.0,
    )
    contradiction_min_ceiling: float = param(
        0.85,
        'The contradiction check (confidence.contradicting_objects) applies only when the '
        "labels' ceiling (the geometric mean of the two scans' label self-agreement, "
        'core/estimation/label_model.py) reaches this (and confidence.min_distinctive_ceiling '
        'trusts the objects): noisier labels make objects of mislabeled distinctive points '
        'that cannot line up. Dev pairs: >= 0.90 clean, 0.74-0.81 with 20 % of the source '
        'labels random (right poses: 1-6 of 8-31 objects in view lined up). 0: always; an '
        'unknown ceiling keeps the check (docs/label_noise.md).',
        low=0.0,
        high=1.0,
    )
    min_distinctive_ceiling: float = param(
        0.5,
        'The distinctive objects choose among the candidates, decide an ambiguity and '
        "contradict a pose only while their classes' label ceiling reaches this: the share "
        'of the points of confidence.distinctive_classes whose nearest other point is one '
        'too, geometric mean of both scans (core/estimation/label_model.py). Dev pairs and '
        'their 40/60 m compositions: 0.65-0.96 with the given labels and with 30-50 % '
        'confusions, 0.06-0.34 with 10-30 % of the labels flipped (10 % flips: a pose 4.7 m '
        'off lined up 2 of 4 objects by chance and replaced the right one); simulated '
        'network labels of the field drives: about 0.6-0.7 per scan. 0: always; an unknown '
        'value (fewer than two such points) trusts them (docs/label_noise.md).',
        low=0.0,
        high=1.0,
    )
    min_label_ceiling: float = param(
        0.6,
        "Refuse every pose while the labels' ceiling (see "
        'confidence.contradiction_min_ceiling) is below this: the labels are too noisy to '
        'vouch for a pose. 40 m dev pairs with 30 % of the labels flipped (ceiling '
        '0.52-0.57): a 42 m slide lined up 14 of 25 distinctive objects on mislabeled points '
        'and passed every other rule; 20 % flips: 0.64-0.70. 0: never; an unknown ceiling '
        'passes (docs/label_noise.md).',
        low=0.0,
        high=1.0,
    )
    distinctive_gain: float = param(
        2.0,
        "The chosen pose's distinctive share must be at least this many times every close "
        "rival's to decide.",
        low=1.0,
        high=100.0,
    )
    decide_margin: float = param(
        0.5,
        'A candidate pose scoring at least (1 - this) x the best verification score replaces '
        'it when it lines up confidence.min_distinctive_objects and confidence.distinctive_gain '
        'times its distinctive share (a zero-motion slide overlaps more than the truth 40 m '
        'apart, but lines up none of its poles).',
        low=0.0,
        high=1.0,
    )
    degeneracy: str = param(
        'inflate',
        'A fine alignment whose translation is constrained less than '
        'confidence.min_localizability along some direction (Hessian eigenvalues) is '
        'reported in /diagnostics (report), also published with its covariance inflated '
        'by confidence.degeneracy_inflation along that direction (inflate), or refused '
        '(refuse).',
        choices=('report', 'inflate', 'refuse'),
    )
    min_localizability: float = param(
        0.02,
        "Smallest ratio of the translation Hessian's smallest to largest eigenvalue "
        '(1: every direction constrained as well).',
        low=0.0,
        high=1.0,
    )
    degeneracy_inflation: float = param(
        100.0,
        'Covariance factor along the weak direction (confidence.degeneracy=inflate).',
        low=1.0,
        high=1e6,
    )
    label_rule: str = param(
        'relative',
        'How the label agreement is judged (core/estimation/label_model.py, docs/label_noise.md): '
        'relative (against the ceiling these labels can give, the geometric mean of the two '
        "scans' self-agreement: min_relative_agreement and label_floor), fixed "
        '(min_label_agreement) or information (the agreement beyond chance against what the '
        'labels give against themselves: min_relative_information; the label-quality stage '
        'sets it for poorer labels, docs/labels.md).',
        choices=('relative', 'fixed', 'information'),
    )
    min_relative_information: float = param(
        0.3,
        'information rule: smallest label agreement beyond chance (Cohen kappa of the '
        "pose's dense label co-occurrence) as a share of the labels' own (the geometric "
        "mean of both scans' kappa against their nearest neighbours): the labels' veto. "
        'Dev pairs: right poses 0.37-1.16 with 30 % flips, 0.37-0.80 with geometric '
        'labels (docs/labels.md).',
        low=0.0,
        high=2.0,
    )
    min_label_information: float = param(
        0.1,
        "Labels whose own agreement beyond chance (the geometric mean of both scans' kappa "
        'against their nearest neighbours) is below this are no better than chance: the '
        'pair is matched and judged as unlabeled (core/labeling/quality.py). Dev pairs: '
        '0.87-0.96 as given, 0.14-0.46 with 30 % flips, 0.01-0.08 with 70 %.',
        low=0.0,
        high=1.0,
    )
    min_relative_agreement: float = param(
        0.75,
        'relative rule: smallest label agreement of the chosen pose as a share of the '
        "labels' ceiling.",
        low=0.0,
        high=2.0,
    )
    label_floor: float = param(
        0.3,
        'relative rule: the label agreement must also reach this, however noisy the labels.',
        low=0.0,
        high=1.0,
    )
    label_model: str = param(
        'fixed',
        'Label compatibility of the agreement: fixed (verification.compatible_classes) or '
        'adaptive (the odometry adds the confusions learned from the label co-occurrence '
        'at accepted poses, core/estimation/label_model.py).',
        choices=('fixed', 'adaptive'),
    )
    label_decay: float = param(
        0.98,
        'adaptive: the learned co-occurrence counts are multiplied by this at every update.',
        low=0.0,
        high=1.0,
    )
    label_min_association: float = param(
        0.15,
        'adaptive: a class pair starts to count as agreeing above this association (how '
        'often a class lies on the other per time it lies on itself, either way), fully at 1.',
        low=0.0,
        high=0.99,
    )
    label_min_count: float = param(
        200.0,
        'adaptive: a class pair is learned only when both classes have at least this much '
        '(range-weighted, in sampled points) co-occurrence with themselves.',
        low=0.0,
        high=1e9,
    )
    count_rule: str = param(
        'fixed',
        'The sparse count a pose needs: fixed (estimator.min_inliers and min_inlier_ratio) '
        'or chance (more than chance_margin times the consensus the estimator wins on '
        'randomly re-paired correspondences of the same pair, and chance_floor, in place of '
        'both; core/estimation/chance.py, docs/confidence.md#acceptance-by-evidence).',
        choices=('fixed', 'chance'),
    )
    chance_shuffles: int = param(
        0,
        'Random re-pairings of the correspondences the estimator runs on to measure the '
        'chance consensus (0: not measured; count_rule chance then falls back to '
        'estimator.min_inliers). Each costs one estimator run.',
        low=0,
        high=100,
    )
    chance_margin: float = param(
        3.0,
        'count_rule chance: a pose needs more than this many times the largest chance '
        'consensus (wrong and unrelated KITTI dev pairs won at most 2.7 times it).',
        low=1.0,
        high=100.0,
    )
    chance_floor: int = param(
        10,
        'count_rule chance: a pose needs at least this many inliers whatever the chance.',
        low=3,
        high=100000,
    )
    chance_max_inliers: int = param(
        200,
        'The chance consensus is measured only for poses with fewer inliers than this (a '
        'stronger consensus passes the count).',
        low=1,
        high=1000000,
    )
