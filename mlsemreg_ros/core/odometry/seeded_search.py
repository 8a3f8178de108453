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
A scan after a lost one: the keyframe searched around the prediction, judged where both see.

When a scan is lost (a degenerate message in place of a real one), the next one is two
strides from everything the odometry has: on the KITTI dev chain, 40 m from the keyframe.
Its prediction over the gap is metres and degrees off, the global registration onto the
keyframe finds nothing, and the map alignment keeps too little of the scan for the
relative inlier rule (docs/confidence.md, "A scan lost in place").

So a scan that is still refused after a gap in the stamps is matched again around the
prediction (:func:`seeds`: turned by :data:`SEED_YAWS_DEG` and moved by
:data:`SEED_ALONG_M` along its heading): guided re-matching onto the keyframe
(core/estimation/guided.py, ``bev_search.guided_radius``), SC2-PCR, and the map alignment
of each estimate. Places along a road keep as many map inliers and sparse inliers as the
truth; what tells them apart is the free space of the two scans. So the refined places are
judged as stage 9 of the pair registration judges a far pose
(core/estimation/covisible_acceptance.py), against the keyframe:

- the best place by covisible overlap reaches ``covisibility.accept_overlap`` with
  ``covisibility.accept_checked`` of its surface checked, tilt within
  ``covisibility.accept_tilt``;
- every other refined place farther than ``confidence.rival_translation`` /
  ``confidence.rival_rotation`` and the place slid ``confidence.slide_distance`` along 8
  directions stay ``covisibility.accept_gap`` below it;
- it also has the best dense score (overlap x label agreement) of the distinct places, its
  SC2-PCR consensus holds ``estimator.min_inliers``, its map alignment keeps
  :data:`~mlsemreg_ros.core.odometry.second_look.GLOBAL_INLIER_FLOOR` of
  ``odometry.min_inlier_fraction``, and every perturbed start of the near-miss check comes
  back to it (``near_miss.*``).

Only the correction bound (a seed is a rough guess) and the relative inlier rule (a scan
40 m from the map overlaps it less) are overruled. ``odometry.seeded_search: false`` turns
it off.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
import time
from typing import Any

from mlsemreg_ros.core.estimation.confidence import slid_poses, tilt_deg
from mlsemreg_ros.core.estimation.covisibility import mutual_covisible_overlap
from mlsemreg_ros.core.estimation.covisible_acceptance import (
    acceptance_refusal,
    best_eligible,
    CovisibleEvidence,
    tilt_refusal,
)
from mlsemreg_ros.core.estimation.estimation import estimate
from mlsemreg_ros.core.estimation.guided import guided_correspondences
from mlsemreg_ros.core.estimation.verification import combined_score
from mlsemreg_ros.core.odometry.second_look import basins, GLOBAL_INLIER_FLOOR
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.trust import Candidate, MAX_TRACKING_GAP
from mlsemreg_ros.core.poses import same_pose
from mlsemreg_ros.core.stages.covisibility import covisible_side
import numpy as np

#: Yaw offsets of the seeds from the prediction (deg): the dev chain's lost scan was 12.9 deg
#: off after the road turned 12 and 9 deg in the two intervals it did not see.
SEED_YAWS_DEG = (-16.0, -8.0, 0.0, 8.0, 16.0)
#: Offsets of the seeds along the prediction's heading (m).
SEED_ALONG_M = (-4.0, 0.0, 4.0)
#: Directions of the slides (as stage 9).
SLIDES = 8


@dataclass(frozen=True)
class Place:
    """One seed's refined place: its map candidate and its evidence against the keyframe."""

    candidate: Candidate
    sparse_inliers: int  # SC2-PCR inliers of the guided correspondences
    T_keyframe_current: np.ndarray  # the refined pose in the keyframe's frame
    dense: float = 0.0  # verification score (overlap x label agreement)
    overlap: float = 0.0  # mutual covisible overlap (accept_points)
    checked: float = 0.0


def seeds(T_predicted: np.ndarray) -> list[np.ndarray]:
    """Return the prediction turned by :data:`SEED_YAWS_DEG` and moved by :data:`SEED_ALONG_M`."""
    return seed_grid(T_predicted, SEED_YAWS_DEG, [(along, 0.0) for along in SEED_ALONG_M])


def seed_grid(
    T_origin: np.ndarray, yaws_deg: Sequence[float], moves: Sequence[Any]
) -> list[np.ndarray]:
    """
    Return ``T_origin`` turned by each of ``yaws_deg`` and moved by each of ``moves``.

    ``moves``: xy offsets (m) in ``T_origin``'s frame; each seed is ``T_origin @ step``, the
    step turning about z and moving, yaw by yaw (the seeded search's seeds, :func:`seeds`; a
    first pair's along its view, ``start_search.view_seeds``).
    """
    out = []
    for yaw in np.radians(yaws_deg):
        for move in moves:
            step = np.eye(4)
            step[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
            step[:2, 3] = move
            out.append(T_origin @ step)
    return out


def search_around_prediction(
    odometry: Any,
    prediction: Any,
    raw: Any,
    chosen: Decision,
    timings: dict[str, float],
) -> Decision:
    """Return ``chosen``, or a place the seeded search accepts (module docstring)."""
    cfg = odometry.config
    registration = getattr(odometry.global_registration, 'registration', None)
    if (
        not cfg.odometry.seeded_search
        or chosen.accepted
        or prediction is None
        or prediction.stamp_gap <= MAX_TRACKING_GAP
        or odometry.keyframe is None
        or registration is None
        or cfg.fine.method == 'off'
    ):
        return chosen
    tic = time.perf_counter()
    try:
        place, refusal = search_seeds(
            odometry, registration, seeds(prediction.T_odom_current), raw.scan
        )
    finally:
        timings['seeded_search_ms'] = 1e3 * (time.perf_counter() - tic)
    return searched(
        chosen,
        place,
        refusal,
        ('seeded search', 'the seeded search around the prediction'),
        cfg.odometry.covariance_scale,
    )


def searched(
    chosen: Decision,
    place: Place | None,
    said: str,
    name: tuple[str, str],
    covariance_scale: float,
) -> Decision:
    """
    Return ``chosen`` rescued by the place a seeded search accepted, or with its refusal noted.

    ``said``: what :func:`search_seeds` said with the place (its refusal when None);
    ``name``: the search's name in a refusal's note and in an acceptance's ("accepted by
    ..."). Shared by the searches around a prediction (here) and from the keyframe
    (core/odometry/start_search.py).
    """
    refused_as, accepted_by = name
    if place is None:
        note = f'{refused_as}: {said}'
        return replace(chosen, reason='; '.join(r for r in (chosen.reason, note) if r))
    note = (
        f'accepted by {accepted_by} (covisible overlap {place.overlap:.3f} of '
        f'{place.checked:.2f} checked; {said})'
    )
    return chosen.rescued(place.candidate, note, covariance_scale)


def search_seeds(
    odometry: Any,
    registration: Any,
    T_seeds: list[np.ndarray],
    scan: Any,
    rejudge: Callable[[Place], tuple[Any, Any] | None] | None = None,
    config: Any = None,
    best_only: bool = False,
) -> tuple[Place | None, str]:
    """
    Return the place the seeds ``T_odom`` lead to and the evidence accepts (None: none).

    ``rejudge(place)``: the scan and the keyframe's scan to measure the places' evidence on
    when the best place implies them (deskewed by its motion, core/odometry/start_search.py;
    None: the scans as they are). ``config``: the configuration the places are judged by
    (None: the odometry's). ``best_only``: only the best place itself may be accepted, not
    another seed's refinement near it.
    """
    cfg, keyframe, tracker = config or odometry.config, odometry.keyframe, odometry.tracker
    target = registration.complete(keyframe.prepared)
    scan = registration.complete(scan)
    scoring = registration.scoring()
    places = []
    for seed in T_seeds:
        T_seed = np.linalg.solve(keyframe.pose, seed)
        corr = guided_correspondences(
            scan, target, T_seed, cfg.bev_search.guided_radius, scoring.compatibility
        )
        if len(corr) < 3:
            continue
        estimated = estimate(
            scan.keypoints[corr.source], target.keypoints[corr.target], cfg.estimator
        )
        if not np.all(np.isfinite(estimated.transform)):
            continue
        candidate = tracker.candidate('global', keyframe.pose @ estimated.transform, scan, cfg)
        T_refined = candidate.alignment.T_target_source
        if not np.all(np.isfinite(T_refined)):
            continue
        places.append(
            Place(candidate, int(estimated.num_inliers), np.linalg.solve(keyframe.pose, T_refined))
        )
    if not places:
        return None, 'no seed gave a place'
    places = _measured(places, scan, target, scoring, cfg)
    cluster, rivals = _cluster(places, cfg)
    best = cluster[0]
    judged = (scan, target) if rejudge is None else rejudge(best) or (scan, target)
    if judged[0] is not scan:  # measured again on the scans the best place implies
        places = _measured(places, *judged, scoring, cfg)
        cluster, rivals = _cluster(places, cfg)
        distinct = cfg.verification.distinct_rotation, cfg.verification.distinct_translation
        if not same_pose(best.T_keyframe_current, cluster[0].T_keyframe_current[None], *distinct)[
            0
        ]:
            return None, 'on the scans the best place implies, another place is best'
    refusal = _place_refusal(cluster[0], rivals, *judged, cfg)
    if refusal:
        return None, refusal
    said = []
    tried = cluster[:1] if best_only else sorted(cluster, key=lambda p: -p.dense)
    for place in tried:  # the finer fit first
        refusal = _own_refusal(place, tracker, scan, cfg)
        if not refusal:
            return place, f'{len(places)} places, {len(cluster)} at this one'
        said.append(refusal)
    return None, '; '.join(said)


def _measured(places: list[Place], scan: Any, target: Any, scoring: Any, cfg: Any) -> list[Place]:
    """Return ``places`` with their dense score and covisible overlap against the keyframe."""
    transforms = np.stack([p.T_keyframe_current for p in places])
    dense = combined_score(*scoring.dense(transforms, scan, target), cfg.verification)
    overlap, checked = _covisible(transforms, scan, target, cfg)
    return [
        replace(p, dense=float(d), overlap=float(o), checked=float(c))
        for p, d, o, c in zip(places, dense, overlap, checked, strict=True)
    ]


def _covisible(
    transforms: np.ndarray, scan: Any, target: Any, cfg: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual covisible overlap and checked share of ``(N, 4, 4)`` keyframe-frame poses."""
    covis = cfg.covisibility
    if not len(transforms):
        return np.zeros(0), np.zeros(0)
    sample = replace(cfg.verification, sample_points=covis.accept_points)
    return mutual_covisible_overlap(
        transforms,
        covisible_side(scan, covis.bin_deg, sample),
        covisible_side(target, covis.bin_deg, sample),
        cfg.verification.overlap_distance,
        covis.margin,
    )


def _cluster(places: list[Place], cfg: Any) -> tuple[list[Place], list[Place]]:
    """
    Split ``places`` into the best one's cluster (best first) and its distinct rivals.

    The best place has the best covisible overlap with enough of it checked. Seeds that
    converge near one another (within ``confidence.rival_*``) are one place: they reach
    about the same overlap, and the map may hold them in basins half a metre apart (on
    the dev chain, 0.21 and 0.42 m from the truth).
    """
    covis, conf = cfg.covisibility, cfg.confidence
    top = max(places, key=lambda p: (p.overlap * (p.checked >= covis.min_checked), p.dense))
    near = same_pose(
        top.T_keyframe_current,
        np.stack([p.T_keyframe_current for p in places]),
        conf.rival_rotation,
        conf.rival_translation,
    )
    cluster = [top] + [p for p, n in zip(places, near, strict=True) if n and p is not top]
    return cluster, [p for p, n in zip(places, near, strict=True) if not n]


def _place_refusal(best: Place, rivals: list[Place], scan: Any, target: Any, cfg: Any) -> str:
    """Why the place is not the one the keyframe sees ('' if it is; module docstring)."""
    covis, conf = cfg.covisibility, cfg.confidence
    denser = [p.dense for p in rivals if p.dense >= best.dense]
    if denser:
        return (
            f'a distinct place scores {max(denser):.3f} on the dense scans >= the best '
            f'place {best.dense:.3f}'
        )
    pose = best.T_keyframe_current
    tilt = tilt_deg(pose)
    refusal = tilt_refusal(tilt, covis)
    if refusal:
        return refusal
    slides = slid_poses(pose, conf.slide_distance, SLIDES)[: SLIDES * (conf.slide_distance > 0)]
    slide_overlap, slide_checked = _covisible(slides, scan, target, cfg)
    evidence = CovisibleEvidence(
        best.overlap,
        best.checked,
        *best_eligible(
            np.array([p.overlap for p in rivals]),
            np.array([p.checked for p in rivals]),
            covis.min_checked,
        ),
        *best_eligible(slide_overlap, slide_checked, covis.min_checked),
        tilt,
    )
    refusal = acceptance_refusal(evidence, covis)
    if refusal:
        return refusal
    return ''


def _own_refusal(place: Place, tracker: Any, scan: Any, cfg: Any) -> str:
    """Why the place's own evidence fails: sparse and map inliers, basins ('' if it holds)."""
    alignment = place.candidate.alignment
    floor = GLOBAL_INLIER_FLOOR * cfg.odometry.min_inlier_fraction
    if alignment.inlier_fraction < floor:
        return (
            f'kept {alignment.inlier_fraction:.2f} of the scan as map inliers < '
            f'{GLOBAL_INLIER_FLOOR:g} x odometry.min_inlier_fraction'
        )
    if place.sparse_inliers < cfg.estimator.min_inliers:
        return (
            f'{place.sparse_inliers} sparse inliers < '
            f'estimator.min_inliers={cfg.estimator.min_inliers}'
        )
    return basins(tracker, place.candidate, scan, cfg).refusal
