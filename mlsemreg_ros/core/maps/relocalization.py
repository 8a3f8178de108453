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
Relocalization without an initial guess: place recognition, then registration (docs/maps.md).

For a query scan (sensor frame, labeled):

1. its semantic scan context picks the candidate keyframes of the store
   (:meth:`mlsemreg_ros.core.maps.place_recognition.PlaceIndex.shortlist`: KD-tree on ring keys,
   re-ranked over every yaw; at most ``map.candidates``, whatever the map size);
2. the query is registered onto each candidate with the full pipeline (ML-SemReg +
   SC2-PCR + verification + confidence + fine alignment), no initial guess;
3. a registration the confidence rule accepts (``RegistrationResult.success``) is refined
   against a submap of the keyframe and its neighbours and refused unless the refinement
   agrees (``map.relocalize_refine``, :mod:`mlsemreg_ros.core.maps.submap_check`); the
   refined pose gives ``T_map_sensor = T_map_keyframe @ T_keyframe_query``. With
   ``map.stop_at_first_accepted`` the first accepted candidate (best scan context first)
   is the answer; else the accepted one with the most sparse inliers.

Quick pass first (``map.quick_first``, with ``map.stop_at_first_accepted``): the candidates
are first registered without the BEV search and the stages after it
(``bev_search.enabled`` false). A pose the first round's confidence stage accepts on
strong evidence (``bev_search.weak_inliers`` or more) is exactly what the full registration
returns, since every stage that searches or rescues needs a refused or weak pose; it is
taken at once. A pose that a later stage of the quick pass rescues is set aside. Only
when no candidate gives one are the candidates registered again with the full path, best
scan context first. A place seen
again is then found at the cost of the cheap stages, and a refused query pays the quick pass
on top of the full one.

No accepted candidate: the query is refused (``found`` false) and no pose is given.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import threading
import time

from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
from mlsemreg_ros.core.maps.place_recognition import Candidate
from mlsemreg_ros.core.maps.submap_check import refine_on_submap, static_points, submap_cloud
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult, VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext, Stage
import numpy as np

#: Diagnostics key of the quick pass: the first round's verdict was an accepted pose on
#: strong evidence (``bev_search.weak_inliers``), so no refused-path stage could run.
FIRST_ROUND_DECIDED = 'quick_first_round_decided'
#: Diagnostics key of the quick pass's screen (``map.quick_defers_retry``): SC2-PCR's
#: sampled graph found fewer than ``estimator.graph_retry_inliers`` inliers, so the
#: estimator would run again on the full graph; the candidate waits for the quick pass.
RETRY_DEFERRED = 'quick_retry_deferred'


def _first_round_decided(context: RegistrationContext) -> bool:
    """Tell whether the pose is accepted on strong evidence now (no stage would search)."""
    return (
        context.evidence is not None
        and not context.diagnostics.get(RETRY_DEFERRED, False)
        and not context.refusal
        and context.evidence.num_inliers >= context.config.bev_search.weak_inliers
    )


class _WrappedStage:
    """A registration stage under the quick pass's own rule: by default, the stage itself."""

    def __init__(self, stage: Stage) -> None:
        """Wrap a stage of the registration (the wrapper keeps its name)."""
        self.stage = stage
        self.name = stage.name

    def wanted(self, context: RegistrationContext) -> bool:
        """Return the wrapped stage's condition."""
        return self.stage.wanted(context)

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Run the wrapped stage."""
        return self.stage.run(context)


class _FirstVerdict(_WrappedStage):
    """The quick pass's confidence stage: it also notes the first round's verdict."""

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Run the wrapped stage and note :data:`FIRST_ROUND_DECIDED`."""
        found = self.stage.run(context)
        context.diagnostics[FIRST_ROUND_DECIDED] = _first_round_decided(context)
        return found


class _WhenDecided(_WrappedStage):
    """
    The quick pass's fine alignment: only for a pose decided in the first round.

    Any other quick result is set aside and the candidate registered again with the full
    path, so refining it would be wasted (one GICP per refused candidate).
    """

    def wanted(self, context: RegistrationContext) -> bool:
        """Return the stage's condition, for a pose decided in the first round."""
        decided = bool(context.diagnostics.get(FIRST_ROUND_DECIDED, False))
        return decided and _first_round_decided(context) and self.stage.wanted(context)


def _would_retry(diagnostics: dict, retry_inliers: int) -> bool:
    """Tell whether SC2-PCR's sampled estimate is one it would run again on the full graph."""
    sampled = diagnostics.get('graph_correspondences', 0) < diagnostics.get('n_correspondences', 0)
    return bool(sampled and diagnostics.get('best_hypothesis_inliers', 0) < retry_inliers)


class _Screened(_WrappedStage):
    """
    The screen's estimator: SC2-PCR without its retry, noting when it would have retried.

    Its registration's ``estimator.graph_retry_inliers`` is 0; the registration's own value
    decides :data:`RETRY_DEFERRED`. Everything up to the estimate is the quick pass's, so an
    estimate that is not deferred is the quick pass's too.
    """

    def __init__(self, stage: Stage, retry_inliers: int) -> None:
        """Wrap the registration's estimation stage."""
        super().__init__(stage)
        self.retry_inliers = retry_inliers

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Estimate on the sampled graph and note :data:`RETRY_DEFERRED`."""
        found = self.stage.run(context)
        deferred = _would_retry(context.diagnostics, self.retry_inliers)
        context.diagnostics[RETRY_DEFERRED] = deferred
        return found


class _UnlessDeferred(_WrappedStage):
    """A stage after the screen's first verdict: skipped for a deferred candidate."""

    def wanted(self, context: RegistrationContext) -> bool:
        """Return the wrapped stage's condition, unless the estimate was deferred."""
        deferred = bool(context.diagnostics.get(RETRY_DEFERRED, False))
        return not deferred and self.stage.wanted(context)


@dataclass
class CandidateTrial:
    """One candidate keyframe and what its registration said."""

    keyframe_id: int
    similarity: float
    accepted: bool
    inliers: int
    message: str
    time_ms: float
    quick: bool = False  # registered in the quick pass (map.quick_first)
    deferred: bool = False  # its screen left it to the quick pass (map.quick_defers_retry)


@dataclass
class Relocalization:
    """The answer to one query."""

    found: bool  # an accepted registration gave T_map_sensor
    T_map_sensor: np.ndarray | None  # (4, 4)
    keyframe_id: int  # the keyframe it was registered onto (-1: none)
    trials: list[CandidateTrial] = field(default_factory=list)
    result: RegistrationResult | None = None  # the accepted registration
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def time_ms(self) -> float:
        """Total wall time."""
        return float(self.timings_ms.get('total_ms', 0.0))


class Relocalizer:
    """Relocalizes scans against a keyframe store with a registration."""

    def __init__(self, registration: Registration, store: KeyframeStore) -> None:
        """Use ``registration`` (its config) and the keyframes of ``store``."""
        self.registration = registration
        self.store = store
        self._quick: tuple[object, Registration] | None = None
        self._screen: tuple[object, Registration] | None = None
        self._ahead: threading.Thread | None = None
        self._stop_ahead = threading.Event()

    def prepare_map(self, background: bool = False) -> threading.Thread | None:
        """
        Prepare what every query needs before the first one (``map.prepare_on_load``).

        The place index (every keyframe's scan context), the quick pass's registration,
        then keyframes completely (:meth:`KeyframeStore.prepare_ahead`) and their submap
        clouds (``map.relocalize_refine``), up to ``map.prepared_cache`` of each.
        ``background``: on a daemon thread (returned; a query meanwhile prepares what it
        needs itself), else before returning.
        """
        self.stop_preparing()
        stop = self._stop_ahead.is_set

        def prepare() -> None:
            store, cfg = self.store, self.store.config
            store.place_index()
            if cfg.map.quick_first:
                self.quick_registration()
                if cfg.map.quick_defers_retry:
                    self.screen_registration()
            store.prepare_ahead(self.registration, stop)
            ids = store.ids
            everyone = set(ids)
            for keyframe_id in ids[: cfg.map.prepared_cache if cfg.map.relocalize_refine else 0]:
                if stop() or store.config is not cfg:
                    break
                submap_cloud(store, keyframe_id, cfg.map.submap_keyframes, everyone, cfg.fine)

        if not background:
            prepare()
            return None
        self._stop_ahead.clear()
        self._ahead = threading.Thread(target=prepare, name='prepare_map', daemon=True)
        self._ahead.start()
        return self._ahead

    def stop_preparing(self) -> None:
        """Stop a background :meth:`prepare_map` and wait for it (at most one keyframe)."""
        if self._ahead is not None:
            self._stop_ahead.set()
            self._ahead.join()
            self._ahead = None

    def quick_registration(self) -> Registration:
        """
        Return the registration that stops before the BEV search (``map.quick_first``).

        The same label map and stage list; made again when the registration's config changes.
        Its fine alignment runs only for a pose the quick pass can keep (:class:`_WhenDecided`).
        """
        config = self.registration.config
        if self._quick is None or self._quick[0] is not config:
            quick = config.replace({'bev_search.enabled': False})
            registration = Registration(quick, self.registration.label_map)
            wrappers = {'confidence': _FirstVerdict, 'fine': _WhenDecided}
            registration.stages = [
                wrappers[stage.name](stage) if stage.name in wrappers else stage
                for stage in self.registration.stages
            ]
            self._quick = (config, registration)
        return self._quick[1]

    def screen_registration(self) -> Registration:
        """
        Return the quick pass's screen (``map.quick_defers_retry``).

        The quick registration with SC2-PCR's retry on the full graph left out: its
        estimator notes :data:`RETRY_DEFERRED` where the retry would run; such a candidate
        is then judged (the registration's result needs a verdict) but not decided, and no
        stage after the confidence stage runs. Any other candidate is registered exactly as
        the quick pass would (up to the first verdict only the estimator reads the retry's
        parameter, and a quick result counts only when decided then).
        """
        config = self.registration.config
        if self._screen is None or self._screen[0] is not config:
            quick = self.quick_registration()
            retry = config.estimator.graph_retry_inliers
            registration = Registration(
                quick.config.replace({'estimator.graph_retry_inliers': 0}),
                self.registration.label_map,
            )
            stages, judged = [], False  # after the first verdict: not for a deferred one
            for stage in quick.stages:
                if stage.name == 'estimator':
                    stages.append(_Screened(stage, retry))
                else:
                    stages.append(_UnlessDeferred(stage) if judged else stage)
                judged = judged or stage.name == 'confidence'
            registration.stages = stages
            self._screen = (config, registration)
        return self._screen[1]

    def relocalize(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        *,
        prepared: PreparedScan | None = None,
        allowed: set[int] | None = None,
    ) -> Relocalization:
        """
        Find ``T_map_sensor`` of a scan (points (N, 3), labels (N,)) without an initial guess.

        ``prepared``: the scan as already prepared by the same registration (saves it).
        ``allowed``: keyframe ids that may be candidates (None: all).
        """
        start = time.perf_counter()
        timings: dict[str, float] = {}
        cfg = self.store.config.map
        if prepared is None:
            prepared = self.registration.prepare(points, labels)
        timings['prepare_ms'] = 1e3 * (time.perf_counter() - start)
        tic = time.perf_counter()
        # the descriptor is computed on the prepared scan (sanitized, learning ids, voxels)
        query = self.store.describe(prepared.points, prepared.labels)
        index, ids = self.store.place_index()
        mask = None if allowed is None else np.array([i in allowed for i in ids], dtype=bool)
        shortlist = index.shortlist(query, cfg, mask)
        timings['place_recognition_ms'] = 1e3 * (time.perf_counter() - tic)
        trials: list[CandidateTrial] = []
        best: tuple[int, RegistrationResult, np.ndarray] | None = None
        tic = time.perf_counter()
        search = self.registration.config.bev_search
        quick_first = cfg.quick_first and cfg.stop_at_first_accepted and search.enabled
        everyone = set(ids) if allowed is None else allowed
        decided: set[int] = set()  # the full path would give the quick pass's result

        def attempt(registration: Registration, candidate: Candidate, kind: str) -> bool:
            """Register onto one candidate; note the trial; True once the answer is found."""
            nonlocal best
            keyframe_id = ids[candidate.index]
            began = time.perf_counter()
            target = self.store.prepared(keyframe_id, self.registration)
            result = registration.register(prepared, target)
            accepted = bool(result.success) and bool(np.all(np.isfinite(result.transform)))
            if kind != 'full' and accepted:  # decided in the first round: the full answer
                accepted = bool(result.diagnostics.get(FIRST_ROUND_DECIDED, False))
                if accepted:
                    decided.add(keyframe_id)
            deferred = bool(result.diagnostics.get(RETRY_DEFERRED, False))
            inliers = int(np.count_nonzero(result.inlier_mask))
            if deferred:  # the sampled estimate's inliers rank it for the quick pass
                waiting.append((-inliers, len(waiting), candidate))
            T_keyframe_query, message = result.transform, result.message
            if accepted and cfg.relocalize_refine:
                check = refine_on_submap(
                    self.store,
                    keyframe_id,
                    static_points(prepared),
                    result.transform,
                    everyone,
                    cfg,
                    self.store.config.fine,
                )
                accepted, T_keyframe_query = check.accepted, check.T_match_current
                message = check.reason or message
            trials.append(
                CandidateTrial(
                    keyframe_id,
                    candidate.similarity,
                    accepted,
                    inliers,
                    message,
                    1e3 * (time.perf_counter() - began),
                    kind != 'full',
                    deferred,
                )
            )
            if accepted and (best is None or inliers > int(np.count_nonzero(best[1].inlier_mask))):
                best = (keyframe_id, result, T_keyframe_query)
            return best is not None and cfg.stop_at_first_accepted

        waiting: list[tuple[int, int, Candidate]] = []  # deferred by the screen
        found = False
        if quick_first:
            screen = cfg.quick_defers_retry
            first = self.screen_registration() if screen else self.quick_registration()
            for candidate in shortlist:
                if found := attempt(first, candidate, 'quick'):
                    break
            if not found and waiting:  # the quick pass of the deferred, most inliers first
                quick = self.quick_registration()
                for _, _, candidate in sorted(waiting, key=lambda w: w[:2]):
                    if found := attempt(quick, candidate, 'quick'):
                        break
        if not found:
            for candidate in shortlist:
                if ids[candidate.index] in decided:
                    continue
                if attempt(self.registration, candidate, 'full'):
                    break
        timings['registration_ms'] = 1e3 * (time.perf_counter() - tic)
        timings['total_ms'] = 1e3 * (time.perf_counter() - start)
        if best is None:
            return Relocalization(False, None, -1, trials, None, timings)
        keyframe_id, result, T_keyframe_query = best
        T_map_sensor = self.store[keyframe_id].T_map_keyframe @ T_keyframe_query
        return Relocalization(True, T_map_sensor, keyframe_id, trials, result, timings)
