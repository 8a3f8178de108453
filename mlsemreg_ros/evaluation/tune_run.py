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
One tuning run of ``mlsemreg tune``, callable from Python: start, run, report.

:func:`tune_parameters` builds the search space and the evaluator, opens (or joins) the
study, measures KISS-ICP once for the bag objective, runs the trials
(:func:`~mlsemreg_ros.evaluation.tuning.run_study`) and writes the trials and plots beside
``out``; it returns a :class:`TuneResult` with the chosen trial's parameter values. The
node parameter file itself is written by the command (``parameter_docs`` sits above this
layer). :class:`TuneConsole` prints the start, the progress and the result. The engine is
:mod:`mlsemreg_ros.evaluation.tuning`; docs/tuning.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TYPE_CHECKING

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation.settings import EvaluationConfig
    from mlsemreg_ros.evaluation.tuning import Dimension, TuneTask


class TuneInputError(ValueError):
    """The data, the search space or the study cannot be used as asked."""


@dataclass(frozen=True)
class TuneOptions:
    """The objective, its data and the study."""

    objective: Literal['pairs', 'bag'] = 'pairs'
    descriptor: Literal['gedi', 'fpfh'] = 'gedi'  # pairs: as eval-pairs --descriptor
    stride: int = 1  # bag: register scan k against k - stride
    max_frames: int | None = None  # bag: stop after this many scans
    trials: int | None = 40  # trials to run now, shared by the workers (0: only report)
    timeout_s: float | None = None  # stop starting trials after this long
    workers: int = 1  # worker processes on this machine (one study)
    storage: str | None = None  # Optuna storage URL (None: out with .db, SQLite)
    study: str = 'mlsemreg'  # an existing study is resumed or joined
    seed: int = 0  # sampler seed (+ worker index)
    space: tuple[str, ...] = ()  # KEY=LOW:HIGH or KEY=A,B items narrowing or adding


@dataclass
class TuneResult:
    """The study after the run, the chosen trial and what was written beside ``out``."""

    study: Any  # optuna.Study
    task: TuneTask
    chosen: Any | None  # the trial of the parameter file (None: no trial completed)
    values: dict[str, Any] | None  # the chosen trial's flat core values
    plots: dict[str, str]  # plot -> path or 'skipped: reason'
    trials_path: Path  # <out stem>_trials.json

    def header(self, out: Path) -> list[str]:
        """Return the comment lines of the node parameter file ``out`` (a trial was chosen)."""
        chosen, names = self.chosen, self.study.metric_names
        return [
            f'Parameters of mlsemreg_node tuned by `mlsemreg tune` (study '
            f'{self.task.study_name!r},',
            f'trial {chosen.number}: {names[0]} {chosen.values[0]:.4g}, '
            f'{names[1]} {chosen.values[1]:.4g}; docs/tuning.md).',
            'Load it with: ros2 run mlsemreg_ros mlsemreg_node --ros-args --params-file '
            f'{out.name}',
            '[unit, range, choices] as enforced by the parameter descriptors.',
        ]


def tune_parameters(
    data: Path,
    core: RegistrationConfig,
    bounds: EvaluationConfig,
    options: TuneOptions,
    out: Path,
    console: TuneConsole | None = None,
) -> TuneResult:
    """
    Tune the parameters on ``data`` from the starting point ``core``; write the trials.

    ``out`` names the node parameter file: the trials (``<stem>_trials.json``), the plots
    and the default SQLite storage go beside it. Raises :class:`TuneInputError` (bad data,
    space or study) and RuntimeError (a worker failed).
    """
    from mlsemreg_ros.core.config import ConfigError
    from mlsemreg_ros.evaluation import tuning

    try:
        dims = tuning.build_space(options.objective, list(options.space))
    except ConfigError as error:
        raise TuneInputError(f'search space: {error}') from None
    evaluator = _evaluator(data, bounds, options)
    url = options.storage or tuning.default_storage(out)
    task = tuning.TuneTask(url, options.study, evaluator, dims, _start(core), options.seed)
    try:
        before = tuning.open_study(task).get_trials(deepcopy=False)
    except ConfigError as error:
        raise TuneInputError(str(error)) from None
    if options.objective == 'bag':
        _measure_kiss_icp(task, console)
    finished_before = sum(t.state.is_finished() for t in before)
    if console is not None:
        console.started(task, core, options.trials, finished_before)
    try:
        study = tuning.run_study(
            task,
            options.trials,
            options.timeout_s,
            options.workers,
            console.update if console is not None else None,
        )
    finally:
        if console is not None:
            console.stopped()
    return _finish(study, task, out)


def _finish(study: Any, task: TuneTask, out: Path) -> TuneResult:
    """Choose the trial, save the plots and the trials beside ``out``."""
    from mlsemreg_ros.evaluation import tuning
    from mlsemreg_ros.evaluation.reports import write_json

    trials = study.get_trials(deepcopy=False)
    chosen = tuning.chosen_trial(study)
    plots = tuning.save_plots(study, out)
    record = {
        'study': task.study_name,
        'storage': task.storage,
        'chosen': chosen.number if chosen is not None else None,
        'pareto': [t.number for t in study.best_trials] if chosen is not None else [],
        'plots': plots,
        'trials': [tuning.trial_summary(t) for t in trials],
    }
    trials_path = out.with_name(f'{out.stem}_trials.json')
    write_json(trials_path, record)
    values = tuning.tuned_values(task, chosen) if chosen is not None else None
    return TuneResult(study, task, chosen, values, plots, trials_path)


def _start(core: RegistrationConfig) -> dict[str, Any]:
    """Return the starting point: the flat values that differ from the defaults."""
    from mlsemreg_ros.core.config import RegistrationConfig

    defaults = RegistrationConfig().to_flat_dict()
    return {k: v for k, v in core.to_flat_dict().items() if v != defaults[k]}


def _evaluator(data: Path, bounds: EvaluationConfig, options: TuneOptions) -> Any:
    from mlsemreg_ros.datasets.pairs import list_pairs
    from mlsemreg_ros.evaluation.tuning import BagEvaluator, PairsEvaluator

    if options.objective == 'pairs':
        if not data.is_dir() or not list_pairs(data):
            raise TuneInputError(f'no pair files (*.npz) in {data}')
        return PairsEvaluator(data, options.descriptor, bounds)
    return BagEvaluator(data, bounds, options.stride, options.max_frames)


def _measure_kiss_icp(task: TuneTask, console: TuneConsole | None) -> None:
    """KISS-ICP's latency on the bag, once per study (kept as a study attribute)."""
    from mlsemreg_ros.evaluation.tuning import open_storage
    import optuna

    study = optuna.load_study(study_name=task.study_name, storage=open_storage(task.storage))
    latency = study.user_attrs.get('kiss_latency_ms_p50')
    if latency is None:
        if console is not None:
            console.note('measuring KISS-ICP on the same scans (the time reference) ...')
        latency = task.evaluator.measure_kiss_icp()
        study.set_user_attr('kiss_latency_ms_p50', latency)
    task.evaluator.kiss_latency_ms = float(latency)


class TuneConsole:
    """
    What ``mlsemreg tune`` prints: the space, a progress bar, the Pareto front and the result.

    ``quiet``: no progress bar and no notes (the tables are printed all the same).
    """

    def __init__(self, quiet: bool = False) -> None:
        """Print on the command's console (tables on stdout, the bar on stderr)."""
        self.quiet = quiet
        self._progress: Any = None
        self._task: Any = None
        self._before = 0

    def note(self, text: str) -> None:
        """Print a line of progress (not when quiet)."""
        from mlsemreg_ros.evaluation.tables import print_text

        if not self.quiet:
            print_text(text)

    def started(
        self, task: TuneTask, core: RegistrationConfig, total: int | None, finished_before: int
    ) -> None:
        """Print the study and the searched space; start the bar of the trials."""
        from mlsemreg_ros.evaluation import tables
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        tables.print_text(f'study {task.study_name!r} in {task.storage}; searched:')
        tables.print_table(space_table(task.space, core))
        self._progress = Progress(
            TextColumn('trials'),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn('{task.fields[status]}'),
            console=tables.console(stderr=True),
            disable=self.quiet,
        )
        self._task = self._progress.add_task('trials', total=total, status='')
        self._before = finished_before
        self._progress.__enter__()

    def update(self, trials: list[Any]) -> None:
        """Show the trials finished in this run and the best accuracy loss of the study."""
        finished = [t for t in trials if t.state.is_finished()]
        done = [t for t in finished if t.values]
        best = min((t.values[0] for t in done), default=None)
        pruned = sum(t.state.name == 'PRUNED' for t in finished)
        status = f'best loss {best:.3f}' if best is not None else ''
        self._progress.update(
            self._task,
            completed=max(len(finished) - self._before, 0),
            status=f'{status}  pruned {pruned}',
        )

    def stopped(self) -> None:
        """Close the bar."""
        if self._progress is not None:
            self._progress.__exit__(None, None, None)
            self._progress = None

    def result(self, result: TuneResult) -> None:
        """Print the trial counts, the Pareto front and where the plots are."""
        from mlsemreg_ros.evaluation import tables

        trials = result.study.get_trials(deepcopy=False)
        states: dict[str, int] = {}
        for t in trials:
            states[t.state.name] = states.get(t.state.name, 0) + 1
        tables.print_text(
            f'study {result.task.study_name!r}: {len(trials)} trials ('
            + ', '.join(f'{n} {s.lower()}' for s, n in sorted(states.items()))
            + ')'
        )
        tables.print_table(pareto_table(result.study, result.chosen))
        for name, where in result.plots.items():
            tables.print_text(f'{name} plot: {where}')

    def written(self, result: TuneResult, out: Path) -> None:
        """Print the chosen trial's parameters against the start, and the file written."""
        from mlsemreg_ros.core.config import RegistrationConfig
        from mlsemreg_ros.evaluation import tables

        chosen, values = result.chosen, result.values or {}
        start = RegistrationConfig().replace(result.task.base).to_flat_dict()
        rows = [[k, str(start[k]), str(values[k])] for k in chosen.params]
        tables.print_table(
            tables.ResultTable(
                ('parameter', 'start', f'trial {chosen.number}'), rows, left_columns=3
            )
        )
        tables.print_text(f'wrote {out}')


def space_table(dims: list[Dimension], core: RegistrationConfig) -> Any:
    """Return the table of the searched parameters and their starting values."""
    from mlsemreg_ros.evaluation.tables import ResultTable

    flat = core.to_flat_dict()
    rows = [[d.key, d.describe(), str(flat[d.key])] for d in dims]
    return ResultTable(('parameter', 'searched', 'start'), rows, left_columns=3)


#: Columns of the Pareto table after the objectives: (header, user attribute, digits).
_COLUMNS = {
    'pairs': (
        ('RR %', 'rr_pct', 1),
        ('wrong', 'wrong_poses', 0),
        ('refused', 'refused_right', 0),
        ('RE deg', 're_deg', 2),
        ('TE cm', 'te_cm', 1),
    ),
    'bag': (
        ('t_err %', 't_err_pct', 3),
        ('wrong', 'wrong_poses', 0),
        ('RR %', 'rr_pct', 1),
        ('latency ms', 'latency_ms_p50', 1),
    ),
}


def pareto_table(study: Any, chosen: Any) -> Any:
    """Return the table of the Pareto front's trials (the chosen one starred)."""
    from mlsemreg_ros.evaluation.tables import cell, ResultTable

    names = study.metric_names or ['loss', 'time']
    columns = _COLUMNS[study.user_attrs.get('search', {}).get('objective', 'pairs')]
    front = sorted(study.best_trials, key=lambda t: tuple(t.values)) if chosen else []
    rows = [
        [
            f'{t.number}{" *" if t.number == chosen.number else ""}',
            cell(t.values[0]),
            cell(t.values[1], 2),
            *(cell(t.user_attrs.get(attr), digits) for _, attr, digits in columns),
        ]
        for t in front
    ]
    headers = ('trial', *names, *(header for header, _, _ in columns))
    return ResultTable(headers, rows, title='Pareto front (* written)')
