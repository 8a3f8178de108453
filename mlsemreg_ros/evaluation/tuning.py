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
Parameter tuning on Optuna: search space from the config metadata, two objectives, workers.

- The search space (:func:`build_space`) is a documented set of parameters
  (:data:`PAIRS_SPACE`, :data:`BAG_SPACE`) whose ranges and choices come from the field
  metadata of :mod:`mlsemreg_ros.core.config` (``low``/``high``/``choices``; int or float
  from the default's type; log scale when the range spans two decades or more).
- Every trial is a configuration checked by the config's own validation
  (:meth:`~mlsemreg_ros.core.config.Settings.replace`): an invalid one is pruned with the
  reason (user attribute ``pruned_reason``), never evaluated nor written.
- Two objectives, both minimized: an accuracy loss (:func:`pairs_scores`,
  :func:`bag_scores`; a wrong accepted pose costs :data:`WRONG_POSE_PENALTY`) and the time
  per frame; the study keeps the Pareto front and :func:`chosen_trial` picks one of it.
- Workers are processes that each call ``study.optimize`` on the same Optuna storage
  (SQLite, a journal file, or a PostgreSQL/MySQL URL shared by several machines).

Usage and the measured runs: docs/tuning.md.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import dataclasses
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import socket
import time
from typing import Any, Protocol
import warnings

from mlsemreg_ros.core.config import ConfigError, load_yaml, RegistrationConfig
from mlsemreg_ros.evaluation.settings import EvaluationConfig

#: Accuracy loss of one wrong accepted pose (accepted, but outside the success bounds):
#: more than losing the whole registration recall (100 percentage points).
WRONG_POSE_PENALTY = 100.0
#: Accuracy loss of refusing every right pose (the confidence test; the node would not
#: publish them): below one missed pair, so RR comes first.
REFUSED_COST = 0.5
#: A numeric range is searched on a log scale when high / low reaches this (two decades).
LOG_SCALE_RATIO = 100.0
#: Names of the two objectives, by ``--objective``.
OBJECTIVE_NAMES = {
    'pairs': ('accuracy loss', 'time per pair [ms]'),
    'bag': ('accuracy loss', 'latency / KISS-ICP'),
}


@dataclass(frozen=True)
class SpaceEntry:
    """Why a parameter is searched by default, and an optional narrower window."""

    why: str
    window: tuple[float, float] | None = None  # clipped to the metadata range


#: The default space of ``--objective pairs`` (docs/tuning.md explains the choice).
PAIRS_SPACE: dict[str, SpaceEntry] = {
    'semantic.local_radius': SpaceEntry(
        'Local-SS radius (eq. 1): too small leaves a keypoint without semantic context, too '
        'large blurs its neighbourhood and costs with its cube.'
    ),
    'semantic.ring_width': SpaceEntry(
        'BMR-SS ring width L (eq. 4): resolution of the landmark signature.'
    ),
    'semantic.ring_count': SpaceEntry(
        'BMR-SS ring count N (eq. 4): with L the receptive field N x L (<= 300 m, pruned).'
    ),
    'semantic.top_k': SpaceEntry(
        'Mask Matching top-K levels: how many scene-similar targets stay allowed.', (1.0, 8.0)
    ),
    'estimator.graph_size': SpaceEntry(
        'SC2-PCR graph sample: the cost grows with its square, too small misses the inliers '
        '(0, no limit, is left out of the window).',
        (10.0, 5000.0),
    ),
    'estimator.inlier_threshold': SpaceEntry(
        'Inlier residual of the hypothesis selection (0.6 m in the paper).'
    ),
    'estimator.compatibility_threshold': SpaceEntry(
        'SC2-PCR d_thr: length consistency of two correspondences.'
    ),
    'confidence.min_inlier_ratio': SpaceEntry(
        'Acceptance threshold: trades refused right poses against accepted wrong ones.',
        (0.0, 0.05),
    ),
    'confidence.min_overlap': SpaceEntry('Acceptance threshold (dense overlap).', (0.0, 0.5)),
    'confidence.min_label_agreement': SpaceEntry(
        'Acceptance threshold (label agreement).', (0.3, 0.9)
    ),
}
#: The default space of ``--objective bag``: the pair space, plus the keypoint count (the
#: pair files bring their own keypoints, a bag does not).
BAG_SPACE: dict[str, SpaceEntry] = {
    **PAIRS_SPACE,
    'keypoints.count': SpaceEntry(
        'Keypoints per scan: the main cost of a frame (the paper: 5000, the node: 2000).',
        (500.0, 5000.0),
    ),
}
DEFAULT_SPACES = {'pairs': PAIRS_SPACE, 'bag': BAG_SPACE}


# -- search space --------------------------------------------------------------------
@dataclass(frozen=True)
class Dimension:
    """One searched parameter: an int or float range, or a list of choices."""

    key: str
    kind: str  # 'int', 'float' or 'categorical'
    low: float | None = None
    high: float | None = None
    log: bool = False
    choices: tuple[Any, ...] = ()

    def suggest(self, trial: Any) -> Any:
        """Ask an Optuna trial for a value of this parameter."""
        if self.kind == 'categorical':
            return trial.suggest_categorical(self.key, list(self.choices))
        if self.kind == 'int':
            return trial.suggest_int(self.key, int(self.low), int(self.high), log=self.log)
        return trial.suggest_float(self.key, float(self.low), float(self.high), log=self.log)

    def contains(self, value: Any) -> bool:
        """Tell whether ``value`` lies in this dimension (e.g. a starting point)."""
        if self.kind == 'categorical':
            return value in self.choices
        return self.low <= value <= self.high

    def describe(self) -> str:
        """E.g. ``float 0.01..10 (log)`` or ``one of nn, mnn``."""
        if self.kind == 'categorical':
            return 'one of ' + ', '.join(map(str, self.choices))
        return f'{self.kind} {self.low:g}..{self.high:g}{" (log)" if self.log else ""}'

    def as_dict(self) -> dict[str, Any]:
        """Plain mapping (a study's user attribute)."""
        return {**dataclasses.asdict(self), 'choices': list(self.choices)}


def _kind_of(key: str) -> tuple[str, dataclasses.Field]:
    f = RegistrationConfig.field_of(key)  # ConfigError for an unknown name
    kind = f.type if isinstance(f.type, str) else getattr(f.type, '__name__', str(f.type))
    return kind, f


def dimension(
    key: str,
    low: float | None = None,
    high: float | None = None,
    choices: Sequence[Any] | None = None,
) -> Dimension:
    """
    Build the dimension of ``key`` from its field metadata, optionally narrowed.

    Numbers: ``low``/``high`` narrow the metadata range (ConfigError outside it); int or
    float from the field's type; log scale when ``low > 0`` and ``high / low >=``
    :data:`LOG_SCALE_RATIO`. Strings and booleans: the metadata choices (booleans: false
    and true), or a subset given as ``choices``. ``choices`` also pins a number to a list.
    """
    kind, f = _kind_of(key)
    meta = f.metadata
    if kind == 'list[str]':
        raise ConfigError(f'{key} is a list of class names; it cannot be searched')
    if choices is not None or kind in ('bool', 'str'):
        allowed = meta['choices'] if kind == 'str' else (False, True) if kind == 'bool' else None
        if kind == 'str' and allowed is None and choices is None:
            raise ConfigError(f'{key} is free text; give its values: --space {key}=A,B')
        picked = tuple(choices) if choices is not None else tuple(allowed)
        if not picked:
            raise ConfigError(f'--space {key}: give at least one value')
        for value in picked:
            if allowed is not None and value not in allowed:
                raise ConfigError(f'--space {key}: {value!r} is not one of {list(allowed)}')
        base = RegistrationConfig()
        for value in picked:  # type and range of each value, by the config's own check
            base.replace({key: value})
        return Dimension(key, 'categorical', choices=picked)
    lo = meta['low'] if low is None else low
    hi = meta['high'] if high is None else high
    if lo is None or hi is None:
        raise ConfigError(f'{key} has no range in its metadata; give one: --space {key}=LOW:HIGH')
    for bound in (lo, hi):
        if meta['low'] is not None and bound < meta['low']:
            raise ConfigError(f'--space {key}: {bound:g} is below its minimum {meta["low"]:g}')
        if meta['high'] is not None and bound > meta['high']:
            raise ConfigError(f'--space {key}: {bound:g} is above its maximum {meta["high"]:g}')
    if lo > hi:
        raise ConfigError(f'--space {key}: low {lo:g} is above high {hi:g}')
    if kind == 'int':
        lo, hi = math.ceil(lo), math.floor(hi)
        if lo > hi:
            raise ConfigError(f'--space {key}: no integer in {low}..{high}')
    log = lo > 0 and hi / lo >= LOG_SCALE_RATIO
    if kind == 'int':
        return Dimension(key, 'int', int(lo), int(hi), log)
    return Dimension(key, 'float', float(lo), float(hi), log)


def default_dimension(key: str, entry: SpaceEntry) -> Dimension:
    """Dimension of a default-space entry: its window clipped to the metadata range."""
    if entry.window is None:
        return dimension(key)
    meta = RegistrationConfig.field_of(key).metadata
    low, high = entry.window
    if meta['low'] is not None:
        low = max(low, meta['low'])
    if meta['high'] is not None:
        high = min(high, meta['high'])
    if low > high:  # the metadata moved away from the window: its whole range
        return dimension(key)
    return dimension(key, low, high)


def parse_space_item(item: str) -> Dimension:
    """``KEY=LOW:HIGH`` (a range) or ``KEY=A,B,C`` (choices; YAML values) -> dimension."""
    key, sep, spec = item.partition('=')
    key, spec = key.strip(), spec.strip()
    if not sep or not key or not spec:
        raise ConfigError(f'--space expects KEY=LOW:HIGH or KEY=A,B,C, got {item!r}')
    kind, _ = _kind_of(key)
    if ':' in spec and kind in ('int', 'float'):
        low_text, _, high_text = spec.partition(':')
        try:
            low, high = float(low_text), float(high_text)
        except ValueError:
            raise ConfigError(f'--space {key}: cannot read the range {spec!r}') from None
        return dimension(key, low, high)
    values = [load_yaml(v.strip()) for v in spec.split(',') if v.strip()]
    if kind == 'float':
        values = [
            float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in values
        ]
    return dimension(key, choices=values)


def build_space(objective: str, items: Sequence[str] = ()) -> list[Dimension]:
    """Build the default space of ``objective``; each ``--space`` item narrows or adds one."""
    space = {
        key: default_dimension(key, entry) for key, entry in DEFAULT_SPACES[objective].items()
    }
    for item in items:
        dim = parse_space_item(item)
        space[dim.key] = dim
    return list(space.values())


# -- objectives ----------------------------------------------------------------------
@dataclass
class TrialScores:
    """The two objective values of a trial and what to record about it."""

    accuracy_loss: float
    time: float
    attrs: dict[str, Any] = field(default_factory=dict)


class Evaluator(Protocol):
    """Scores one configuration (picklable: it is sent to the worker processes)."""

    objective: str  # 'pairs' or 'bag' (names of the objectives: OBJECTIVE_NAMES)

    def __call__(self, config: RegistrationConfig) -> TrialScores:
        """Evaluate ``config``; return its scores."""
        ...


def pairs_scores(report: dict[str, Any], bounds: EvaluationConfig) -> TrialScores:
    """
    Scores of an eval-pairs report: RR first, then refused right poses and RE/TE.

    ``loss = (100 - RR) + WRONG_POSE_PENALTY x wrong + REFUSED_COST x refused / n
    + 0.5 x error`` over ``n`` pairs: a missed pair costs ``100 / n``; an accepted pose
    outside the success bounds costs :data:`WRONG_POSE_PENALTY`; ``refused`` counts the
    successful pairs that the confidence test refused (the node would not publish them)
    and ``error`` is the mean of ``(RE / max RE + TE / max TE) / 2`` over the successful
    pairs (<= 1). The last two terms stay below 1, so with up to 100 pairs one more
    successful pair always wins. Time: mean ms per pair (both clouds prepared and
    registered).
    """
    rows, summary = report['pairs'], report['summary']
    rr = float(summary['registration_recall_pct'] or 0.0)
    ok = [r for r in rows if r['success']]
    wrong = sum(1 for r in rows if r.get('accepted', True) and not r['success'])
    refused = sum(1 for r in ok if not r.get('accepted', True))
    error = 0.0
    if ok:
        max_re = max(bounds.max_rotation_deg, 1e-9)
        max_te = max(100.0 * bounds.max_translation_m, 1e-9)
        error = sum(
            0.5 * (r['rotation_error_deg'] / max_re + r['translation_error_cm'] / max_te)
            for r in ok
        ) / len(ok)
    loss = (100.0 - rr) + WRONG_POSE_PENALTY * wrong + REFUSED_COST * refused / max(len(rows), 1)
    loss += 0.5 * min(error, 1.0)
    time_ms = float(summary['time_ms'].get('total_ms', 0.0))
    attrs = {
        'rr_pct': rr,
        'wrong_poses': wrong,
        'refused_right': refused,
        're_deg': summary.get('rotation_error_deg'),
        'te_cm': summary.get('translation_error_cm'),
        'n': len(rows),
    }
    return TrialScores(loss, time_ms, attrs)


@dataclass
class PairsEvaluator:
    """Register every pair file of a folder, as ``mlsemreg eval-pairs`` does."""

    directory: Path
    descriptor: str = 'gedi'
    bounds: EvaluationConfig = field(default_factory=EvaluationConfig)
    objective: str = 'pairs'

    def __call__(self, config: RegistrationConfig) -> TrialScores:
        """Evaluate the pairs with ``config``; see :func:`pairs_scores`."""
        from mlsemreg_ros.evaluation.pairs import evaluate_directory

        report = evaluate_directory(
            self.directory, self.descriptor, config, self.bounds, progress=False
        )
        return pairs_scores(report, self.bounds)


def bag_scores(
    records: Sequence[Any], summary: dict[str, Any], kiss_latency_ms: float
) -> TrialScores:
    """
    Scores of a replayed sequence: drift and wrong poses, then latency against KISS-ICP.

    ``loss = t_err + WRONG_POSE_PENALTY x wrong`` with ``t_err`` the KITTI translation
    error (%; on a sequence too short for it, the ATE RMSE in % of the path) and ``wrong``
    the accepted scans outside the success bounds. Time: median latency of a scan divided
    by KISS-ICP's on the same scans.
    """
    wrong = sum(
        1
        for r in records
        if r.registered and r.accepted and not r.success and math.isfinite(r.gt_x)
    )
    t_err = summary.get('kitti_t_err_pct')
    if t_err is None:
        path = summary.get('path_length_m') or 0.0
        ate = summary.get('ate_rmse_m')
        t_err = 100.0 * ate / path if ate is not None and path > 0 else 100.0
    latency = summary.get('latency_ms_p50') or math.inf
    attrs = {
        't_err_pct': float(t_err),
        'wrong_poses': wrong,
        'rr_pct': summary.get('registration_recall_pct'),
        'latency_ms_p50': summary.get('latency_ms_p50'),
        'n': len(records),
    }
    return TrialScores(float(t_err) + WRONG_POSE_PENALTY * wrong, latency / kiss_latency_ms, attrs)


@dataclass
class BagEvaluator:
    """Replay a bag through the node's odometry, as ``mlsemreg eval-bag`` does."""

    bag: Path
    bounds: EvaluationConfig = field(default_factory=EvaluationConfig)
    stride: int = 1
    max_frames: int | None = None
    kiss_latency_ms: float = math.nan  # filled by :meth:`measure_kiss_icp`
    objective: str = 'bag'

    def _replay(self, estimator: Any) -> Any:
        from mlsemreg_ros.datasets.factory import open_scan_source
        from mlsemreg_ros.evaluation.replay import replay, ReplayOptions

        source = open_scan_source(self.bag)
        try:
            options = ReplayOptions(self.stride, self.max_frames, progress=False)
            return replay(source, estimator, self.bounds, options)
        finally:
            source.close()

    def measure_kiss_icp(self) -> float:
        """Median latency of KISS-ICP on the same scans (ms), the reference of the time."""
        from mlsemreg_ros.evaluation.estimators import KissIcpEstimator
        from mlsemreg_ros.evaluation.scoring import summarize_run

        summary = summarize_run(self._replay(KissIcpEstimator()))
        self.kiss_latency_ms = float(summary['latency_ms_p50'])
        return self.kiss_latency_ms

    def __call__(self, config: RegistrationConfig) -> TrialScores:
        """Replay the bag with ``config``; see :func:`bag_scores`."""
        from mlsemreg_ros.core.odometry import Odometry
        from mlsemreg_ros.core.pipeline import Registration
        from mlsemreg_ros.evaluation.estimators import OdometryEstimator
        from mlsemreg_ros.evaluation.scoring import run_details, summarize_run

        run = self._replay(OdometryEstimator(Odometry(Registration(config))))
        summary = summarize_run(run)
        summary['path_length_m'] = run_details(run)['path_length_m']
        return bag_scores(run.records, summary, self.kiss_latency_ms)


# -- trials and studies --------------------------------------------------------------
@dataclass
class TuneTask:
    """What every worker needs: the storage, the study, the space and the evaluator."""

    storage: str
    study_name: str
    evaluator: Any  # an Evaluator
    space: list[Dimension]
    base: dict[str, Any] = field(default_factory=dict)  # flat core values of the start
    seed: int = 0


def run_trial(trial: Any, task: TuneTask) -> tuple[float, float]:
    """
    Run one trial (the objective of every worker): suggest, validate (prune), evaluate.

    The suggestion is applied to the starting configuration by the config's own
    validation; a ConfigError prunes the trial (``optuna.TrialPruned``) and records the
    reason in the user attribute ``pruned_reason``.
    """
    import optuna

    values = {dim.key: dim.suggest(trial) for dim in task.space}
    trial.set_user_attr('worker', f'{socket.gethostname()}:{os.getpid()}')
    try:
        config = RegistrationConfig().replace(task.base).replace(values)
    except ConfigError as error:
        trial.set_user_attr('pruned_reason', str(error))
        raise optuna.TrialPruned(str(error)) from None
    scores = task.evaluator(config)
    for name, value in scores.attrs.items():
        trial.set_user_attr(name, value)
    return scores.accuracy_loss, scores.time


def open_storage(url: str) -> Any:
    """
    Open the Optuna storage of ``url``.

    ``journal:PATH`` or a path ending in ``.log``/``.journal``: a journal file
    (``JournalStorage`` with ``JournalFileBackend``); anything else is a database URL
    (``sqlite:///study.db``, ``postgresql://user:pass@host/db``, ``mysql://...``).
    """
    import optuna
    from optuna.storages.journal import JournalFileBackend

    path = url.removeprefix('journal:')
    if url.startswith('journal:') or url.endswith(('.log', '.journal')):
        return optuna.storages.JournalStorage(JournalFileBackend(path))
    if '://' not in url:
        raise ConfigError(
            f'--storage {url!r}: give a database URL (sqlite:///study.db, '
            'postgresql://..., mysql://...) or a journal file (journal:study.log)'
        )
    return url


def default_storage(out: Path) -> str:
    """Return the default storage: a SQLite file beside the output (``x.yaml`` -> ``x.db``)."""
    return f'sqlite:///{out.with_suffix(".db").resolve()}'


def make_sampler(seed: int) -> Any:
    """Multi-objective TPE (a worker index is added to the seed: no two workers alike)."""
    import optuna

    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=10, multivariate=True)


def _space_record(task: TuneTask) -> dict[str, Any]:
    return {
        'objective': task.evaluator.objective,
        'space': [d.as_dict() for d in task.space],
        'base': task.base,
    }


def open_study(task: TuneTask, seed_offset: int = 0, wait_s: float = 60.0) -> Any:
    """
    Create the study, or load it to resume or join it (ConfigError if it is another search).

    The process that creates the study records its objective, space and starting point as
    user attributes and enqueues the starting point (when it lies in the space): trial 0
    measures the start. A process that joins a study being created waits up to ``wait_s``
    for that record.
    """
    import optuna

    storage = open_storage(task.storage)
    sampler = make_sampler(task.seed + seed_offset)
    record = _space_record(task)
    try:
        study = optuna.create_study(
            storage=storage,
            study_name=task.study_name,
            directions=['minimize', 'minimize'],
            sampler=sampler,
        )
    except optuna.exceptions.DuplicatedStudyError:
        study = optuna.load_study(study_name=task.study_name, storage=storage, sampler=sampler)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')  # set_metric_names is marked experimental
            study.set_metric_names(list(OBJECTIVE_NAMES[task.evaluator.objective]))
        start = {d.key: task.base.get(d.key, _default(d.key)) for d in task.space}
        if all(d.contains(start[d.key]) for d in task.space):
            study.enqueue_trial(start, user_attrs={'start': True})
        study.set_user_attr('search', record)
        return study
    deadline = time.monotonic() + wait_s
    while (stored := study.user_attrs.get('search')) is None and time.monotonic() < deadline:
        time.sleep(0.5)  # created a moment ago by another process
    if stored != record:
        changed = [k for k in record if (stored or {}).get(k) != record[k]]
        raise ConfigError(
            f'study {task.study_name!r} in {task.storage} was created with another '
            f'{", ".join(changed)}; give the same DATA, --objective, --space, --config and '
            '--set to join it, or another --study'
        )
    return study


def _default(key: str) -> Any:
    return RegistrationConfig().to_flat_dict()[key]


def worker(task: TuneTask, n_trials: int | None, timeout: float | None, index: int) -> None:
    """One worker process: load the study and optimize on it (``study.optimize``)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(
        study_name=task.study_name,
        storage=open_storage(task.storage),
        sampler=make_sampler(task.seed + index),
    )
    study.optimize(
        lambda trial: run_trial(trial, task),
        n_trials=n_trials,
        timeout=timeout,
        catch=(Exception,),  # a crashing configuration is a failed trial, not a dead worker
        gc_after_trial=True,
    )


def split_trials(trials: int | None, workers: int) -> list[int | None]:
    """Share ``trials`` among ``workers`` (the first ones take the remainder)."""
    if trials is None:
        return [None] * workers
    return [trials // workers + (i < trials % workers) for i in range(workers)]


def run_study(
    task: TuneTask,
    trials: int | None,
    timeout: float | None = None,
    workers: int = 1,
    on_progress: Callable[[list[Any]], None] | None = None,
    poll_s: float = 1.0,
) -> Any:
    """
    Run ``trials`` more trials of the study on ``workers`` processes; return the study.

    Each worker is a spawned process calling :func:`worker` (``study.optimize`` on the
    shared storage); the trials are split among them so none is lost or run twice. With
    one worker the trials run in this process, and so does an enqueued start before the
    workers begin. ``on_progress`` gets the study's trials after every trial run here
    and every ``poll_s`` while the workers run.
    """
    import multiprocessing

    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = open_study(task)

    def callback(study_: Any, _: Any) -> None:
        if on_progress is not None:
            on_progress(study_.get_trials(deepcopy=False))

    def optimize_here(n_trials: int | None) -> None:
        study.optimize(
            lambda trial: run_trial(trial, task),
            n_trials=n_trials,
            timeout=timeout,
            catch=(Exception,),
            callbacks=[callback],
            gc_after_trial=True,
        )

    if workers <= 1:
        optimize_here(trials)
        return study
    # The enqueued start runs here first: two SQLite workers could both pop a waiting
    # trial (SQLite has no row locks), and one would then tell a finished trial.
    waiting = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.WAITING,))
    if waiting and (trials is None or trials > 0):
        first = len(waiting) if trials is None else min(len(waiting), trials)
        optimize_here(first)
        trials = None if trials is None else trials - first
    context = multiprocessing.get_context('spawn')
    processes = [
        context.Process(target=worker, args=(task, n, timeout, i), name=f'tune-worker-{i}')
        for i, n in enumerate(split_trials(trials, workers))
        if n is None or n > 0
    ]
    for process in processes:
        process.start()
    try:
        while any(p.is_alive() for p in processes):
            if on_progress is not None:
                on_progress(study.get_trials(deepcopy=False))
            time.sleep(poll_s)
    finally:
        for process in processes:
            process.join()
    failed = [p.name for p in processes if p.exitcode != 0]
    if failed:
        raise RuntimeError(f'tuning workers exited with an error: {", ".join(failed)}')
    study = optuna.load_study(  # a fresh view of every worker's trials
        study_name=task.study_name, storage=open_storage(task.storage), sampler=study.sampler
    )
    if on_progress is not None:
        on_progress(study.get_trials(deepcopy=False))
    return study


# -- results -------------------------------------------------------------------------
def completed(study: Any) -> list[Any]:
    """Return the study's completed trials."""
    import optuna

    return study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))


def chosen_trial(study: Any) -> Any | None:
    """
    Pick the trial written to the parameter file (None when no trial completed).

    The rule: on the Pareto front, the lowest accuracy loss; ties broken by the lower time.
    """
    front = study.best_trials if completed(study) else []
    return min(front, key=lambda t: (t.values[0], t.values[1]), default=None)


def tuned_values(task: TuneTask, trial: Any) -> dict[str, Any]:
    """Flat core values of a trial: the starting point with the trial's parameters."""
    config = RegistrationConfig().replace(task.base).replace(dict(trial.params))
    return config.to_flat_dict()


def save_plots(study: Any, out: Path) -> dict[str, str]:
    """
    Optuna's matplotlib plots beside ``out``: history, parameter importance, Pareto front.

    Returns ``{plot: path or 'skipped: reason'}`` (importance needs two completed trials
    with different parameters; nothing is plotted without a completed trial).
    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as ovm

    names = study.metric_names or list(OBJECTIVE_NAMES['pairs'])
    n_done = len(completed(study))
    plots: dict[str, Callable[[], Any]] = {
        'history': lambda: ovm.plot_optimization_history(
            study, target=lambda t: t.values[0], target_name=names[0]
        ),
        'importance': lambda: ovm.plot_param_importances(
            study, target=lambda t: t.values[0], target_name=names[0]
        ),
        'pareto': lambda: ovm.plot_pareto_front(study, target_names=names),
    }
    out_paths: dict[str, str] = {}
    warnings.filterwarnings('ignore', module='optuna')  # experimental / importance notes
    for name, plot in plots.items():
        need = 2 if name == 'importance' else 1
        if n_done < need:
            out_paths[name] = f'skipped: {n_done} completed trial(s), {need} needed'
            continue
        path = out.with_name(f'{out.stem}_{name}.png')
        try:
            axes = plot()
            axes.figure.set_size_inches(8, 5)
            axes.figure.tight_layout()
            axes.figure.savefig(path, dpi=100)
            out_paths[name] = str(path)
        except (ValueError, RuntimeError, ZeroDivisionError) as error:
            out_paths[name] = f'skipped: {error}'
        finally:
            plt.close('all')
    return out_paths


def trial_summary(trial: Any) -> dict[str, Any]:
    """One row of the results: number, values, recorded metrics and parameters."""
    return {
        'number': trial.number,
        'state': trial.state.name,
        'values': list(trial.values) if trial.values else None,
        'params': dict(trial.params),
        'user_attrs': dict(trial.user_attrs),
        'duration_s': trial.duration.total_seconds() if trial.duration else None,
        'started': trial.datetime_start.isoformat() if trial.datetime_start else None,
        'completed': trial.datetime_complete.isoformat() if trial.datetime_complete else None,
    }
