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

"""A map prepared when it loads: queries pay for no keyframe, and answer as before (issue 30)."""

import dataclasses

from hypothesis import given, settings
from hypothesis import strategies as st
from mlsemreg_ros.core.alignment.alignment import AlignmentCloud
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.maps.place_recognition import (
    Candidate,
    context_similarity,
    PlaceDescriptor,
    PlaceIndex,
)
from mlsemreg_ros.core.maps.relocalization import Relocalizer
from mlsemreg_ros.core.maps.submap_check import submap_cloud, submap_points
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
import numpy as np
import pytest
from street_map import street_keyframe_store, STREET_SEED


def _query() -> tuple[np.ndarray, np.ndarray]:
    world, labels = street_scene(seed=STREET_SEED)
    return scan_at(world, labels, motion(-40.0, (7.0, -1.0, 0.0)), seed=999, max_points=15000)


class _CountingRegistration(Registration):
    """A registration that counts the scans it prepares."""

    prepared_scans = 0

    def prepare(self, *args, **kwargs):
        self.prepared_scans += 1
        return super().prepare(*args, **kwargs)


def _spread_reference(index: PlaceIndex, query, neighbours, config) -> list[Candidate]:
    """Choose as the greedy loop did before (one distance per chosen candidate)."""
    similarity, yaw = context_similarity(query, index.contexts[neighbours])
    chosen: list[Candidate] = []
    for i in np.argsort(-similarity, kind='stable'):
        at = int(neighbours[i])
        if config.candidate_separation > 0 and any(
            np.linalg.norm(index.positions[at] - index.positions[c.index])
            < config.candidate_separation
            for c in chosen
        ):
            continue
        chosen.append(Candidate(at, float(similarity[i]), float(yaw[i])))
        if len(chosen) >= config.candidates:
            break
    return chosen


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    count=st.integers(1, 60),
    separation=st.sampled_from([0.0, 1.0, 3.0, 8.0]),
    candidates=st.integers(1, 7),
    places=st.integers(1, 20),
)
def test_the_vectorized_spread_chooses_as_the_greedy_loop(
    seed: int, count: int, separation: float, candidates: int, places: int
) -> None:
    rng = np.random.default_rng(seed)
    config = dataclasses.replace(
        RegistrationConfig().map, candidate_separation=separation, candidates=candidates
    )
    spots = rng.uniform(-20, 20, (places, 3))  # copies of a few places, and noise
    positions = spots[rng.integers(0, places, count)] + rng.normal(0, 1.0, (count, 3))
    contexts = rng.random((count, 2, 4, 12)).astype(np.float32)
    contexts[rng.random(count) < 0.3] = contexts[0]  # ties in similarity
    descriptors = [PlaceDescriptor(c, c.mean(axis=2).reshape(-1)) for c in contexts]
    index = PlaceIndex(descriptors, positions)
    query = descriptors[int(rng.integers(0, count))]
    neighbours = rng.permutation(count)[: int(rng.integers(1, count + 1))]
    assert index._spread(query, neighbours, config) == _spread_reference(
        index, query, neighbours, config
    )


@pytest.fixture(scope='module')
def config() -> RegistrationConfig:
    return RegistrationConfig().replace({'map.prepared_cache': 3})


def test_a_prepared_map_answers_as_before_and_a_prepared_keyframe_costs_no_preparation(
    config: RegistrationConfig,
) -> None:
    points, labels = _query()
    answers = []
    for ahead in (False, True):
        store = street_keyframe_store(config)
        registration = _CountingRegistration(config, store.label_map)
        relocalizer = Relocalizer(registration, store)
        if ahead:
            relocalizer.prepare_map()
            # the first map.prepared_cache keyframes, completely, and their submaps
            assert [store.is_prepared(i) for i in store.ids] == [True] * 3 + [False] * 2
            for i in store.ids[:3]:
                scan = store.prepared(i, registration)
                assert scan.pending_features is None and (0.0, 20) in scan.alignment_clouds
            assert len(store._derived) == 3
        before = registration.prepared_scans
        found = relocalizer.relocalize(points, labels)
        tried = {t.keyframe_id for t in found.trials}
        fresh = len(tried - set(store.ids[:3])) if ahead else len(tried)
        assert registration.prepared_scans - before == 1 + fresh  # the query and fresh ones
        answers.append(found)
    before, after = answers
    assert before.found and after.found and before.keyframe_id == after.keyframe_id
    assert [t.keyframe_id for t in before.trials] == [t.keyframe_id for t in after.trials]
    np.testing.assert_allclose(before.T_map_sensor, after.T_map_sensor, atol=1e-9)


def test_a_background_preparation_stops_and_a_query_meanwhile_answers_the_same(
    config: RegistrationConfig,
) -> None:
    points, labels = _query()
    reference = Relocalizer(Registration(config), street_keyframe_store(config)).relocalize(
        points, labels
    )
    store = street_keyframe_store(config)
    relocalizer = Relocalizer(Registration(config, store.label_map), store)
    thread = relocalizer.prepare_map(background=True)
    assert thread is not None
    found = relocalizer.relocalize(points, labels)  # while it prepares
    relocalizer.stop_preparing()
    assert not thread.is_alive()
    assert found.found and found.keyframe_id == reference.keyframe_id
    np.testing.assert_allclose(found.T_map_sensor, reference.T_map_sensor, atol=1e-9)


def test_a_cached_submap_is_dropped_when_the_map_changes(config: RegistrationConfig) -> None:
    store = street_keyframe_store(config)
    everyone = set(store.ids)
    first, used = submap_cloud(store, store.ids[2], 3, everyone, config.fine)
    again, _ = submap_cloud(store, store.ids[2], 3, everyone, config.fine)
    assert again is first and used == 5
    fewer, used = submap_cloud(store, store.ids[2], 3, {store.ids[2]}, config.fine)
    assert fewer is not first and used == 1  # another submap: its own entry
    moved = {i: store[i].T_map_keyframe @ motion(0.0, (0.5, 0.0, 0.0)) for i in store.ids[:1]}
    store.set_poses(moved)
    rebuilt, _ = submap_cloud(store, store.ids[2], 3, everyone, config.fine)
    assert rebuilt is not first
    fresh = AlignmentCloud.build(
        submap_points(store, store.ids[2], 3, everyone)[0],
        config.fine.downsampling_resolution,
        config.fine.pair_num_neighbors,
    )

    def rows(cloud: AlignmentCloud) -> np.ndarray:  # small_gicp's voxel order may vary
        return cloud.points[np.lexsort(cloud.points.T)]

    np.testing.assert_allclose(rows(rebuilt), rows(fresh), atol=1e-9)  # from the new poses
    store.remove(store.ids[-1])
    assert submap_cloud(store, store.ids[2], 3, everyone, config.fine)[0] is not rebuilt


def _relocalize(config: RegistrationConfig, points, labels):
    store = street_keyframe_store(config)
    return Relocalizer(Registration(config, store.label_map), store).relocalize(points, labels)


def test_the_screen_leaves_the_answer_as_it_was(config: RegistrationConfig) -> None:
    """A candidate found without SC2-PCR's retry is registered as by the quick pass."""
    points, labels = _query()
    screened = _relocalize(config, points, labels)
    plain = _relocalize(config.replace({'map.quick_defers_retry': False}), points, labels)
    assert screened.found and plain.found and screened.keyframe_id == plain.keyframe_id
    assert [t.keyframe_id for t in screened.trials] == [t.keyframe_id for t in plain.trials]
    assert not any(t.deferred for t in screened.trials)
    np.testing.assert_allclose(screened.T_map_sensor, plain.T_map_sensor, atol=1e-12)


def test_candidates_the_estimator_would_retry_wait_and_then_go_most_inliers_first(
    config: RegistrationConfig,
) -> None:
    """Every sampled estimate retried (a huge retry bound): all wait, most inliers go first."""
    points, labels = _query()
    config = config.replace({'estimator.graph_retry_inliers': 100000})
    screened = _relocalize(config, points, labels)
    waited = [t for t in screened.trials if t.deferred]
    assert len(waited) == config.map.candidates and not any(t.accepted for t in waited)
    count = len(waited)
    assert screened.trials[:count] == waited  # the screen first, every candidate
    after = screened.trials[count:]
    assert after and all(t.quick and not t.deferred for t in after) and after[-1].accepted
    ranked = sorted(waited, key=lambda t: -t.inliers)  # stable: best scan context on ties
    assert [t.keyframe_id for t in after] == [t.keyframe_id for t in ranked[: len(after)]]
    truth = motion(-40.0, (7.0, -1.0, 0.0))
    error = np.linalg.inv(truth) @ screened.T_map_sensor
    assert screened.found and np.linalg.norm(error[:3, 3]) < 0.3
