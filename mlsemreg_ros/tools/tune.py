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
``mlsemreg tune DATA``: tune the node's parameters on pair files or a bag with Optuna.

The engine is :mod:`mlsemreg_ros.evaluation.tuning`; this module is its command line:
the starting point (``--config``/``--set``, as eval-pairs), the space (``--space``), the
study (``--storage``, ``--study``, ``--workers``), then the progress, the table of the
Pareto trials, the plots and the tuned parameter file (``--out``). docs/tuning.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    DATA,
    LabelsOption,
    OUTPUT,
    PARAMETERS,
    QuietOption,
    SetOption,
    with_labels,
)
import typer

HELP = (
    'Tune the parameters on pair files or a bag with Optuna (accuracy against time, '
    'Pareto front; several workers share one study) and write the node parameter file.'
)
STUDY = 'Study'


def tune(
    data: Annotated[
        Path,
        typer.Argument(
            metavar='DATA', exists=True, help='folder of pair files (pairs) or a bag (bag)'
        ),
    ],
    objective: Annotated[
        Literal['pairs', 'bag'],
        typer.Option(
            help='pairs: RR first, then RE/TE, against time per pair; bag: t_err and wrong '
            'poses against the latency ratio to KISS-ICP',
            rich_help_panel=DATA,
        ),
    ] = 'pairs',
    descriptor: Annotated[
        Literal['gedi', 'fpfh'],
        typer.Option(help='pairs: as eval-pairs --descriptor', rich_help_panel=DATA),
    ] = 'gedi',
    stride: Annotated[
        int, typer.Option(min=1, help='bag: register scan k against k - S', rich_help_panel=DATA)
    ] = 1,
    max_frames: Annotated[
        int | None,
        typer.Option(min=1, help='bag: stop after this many scans', rich_help_panel=DATA),
    ] = None,
    trials: Annotated[
        int | None,
        typer.Option(
            min=0,
            help='trials to run now, shared by the workers (0: only write the result)',
            rich_help_panel=STUDY,
        ),
    ] = 40,
    timeout: Annotated[
        float | None,
        typer.Option(
            min=1.0, help='stop starting trials after this many s', rich_help_panel=STUDY
        ),
    ] = None,
    workers: Annotated[
        int,
        typer.Option(
            min=1, help='worker processes on this machine (one study)', rich_help_panel=STUDY
        ),
    ] = 1,
    storage: Annotated[
        str | None,
        typer.Option(
            metavar='URL',
            help='Optuna storage: sqlite:///x.db, postgresql://..., mysql://..., or '
            'journal:FILE (default: OUT with .db, SQLite)',
            rich_help_panel=STUDY,
        ),
    ] = None,
    study: Annotated[
        str,
        typer.Option(
            help='study name: an existing one is resumed or joined', rich_help_panel=STUDY
        ),
    ] = 'mlsemreg',
    seed: Annotated[
        int, typer.Option(help='sampler seed (+ worker index)', rich_help_panel=STUDY)
    ] = 0,
    space: Annotated[
        list[str] | None,
        typer.Option(
            '--space',
            metavar='KEY=LOW:HIGH|A,B',
            help='narrow or add a searched parameter (repeatable), e.g. '
            '--space estimator.graph_size=100:1000 --space matcher.kind=nn,mnn',
            rich_help_panel=PARAMETERS,
        ),
    ] = None,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    out: Annotated[
        Path,
        typer.Option(
            '--out',
            dir_okay=False,
            help='the tuned node parameter file; plots and the trials beside it',
            rich_help_panel=OUTPUT,
        ),
    ] = Path('params.yaml'),
    quiet: QuietOption = False,
) -> int:
    """Tune the parameters with Optuna; write the node parameter file (alias mlsemreg-tune)."""
    import warnings

    from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
    from mlsemreg_ros.evaluation import tables, tuning
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.tools.common import settings
    import optuna

    warnings.filterwarnings('ignore', message='.*is experimental')
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    core, evaluation = settings(
        (RegistrationConfig, EvaluationSettings), config, with_labels(overrides, labels)
    )
    try:
        node_values = NodeConfig.from_file(config).to_flat_dict() if config is not None else {}
    except ConfigError as error:
        raise CommandError(f'configuration error: {error}', 2) from None
    try:
        dims = tuning.build_space(objective, list(space or []))
    except ConfigError as error:
        raise CommandError(f'search space: {error}', 2) from None
    evaluator = _evaluator(objective, data, descriptor, evaluation.evaluation, stride, max_frames)
    url = storage or tuning.default_storage(out)
    task = tuning.TuneTask(url, study, evaluator, dims, _start(core), seed)
    try:
        before = tuning.open_study(task).get_trials(deepcopy=False)
    except ConfigError as error:
        raise CommandError(str(error), 2) from None
    if objective == 'bag':
        _measure_kiss_icp(task, quiet)
    tables.print_text(f'study {study!r} in {url}; searched:')
    tables.print_table(_space_table(dims, core))
    progress = _Progress(trials, quiet, sum(t.state.is_finished() for t in before))
    with progress:
        try:
            result = tuning.run_study(task, trials, timeout, workers, progress.update)
        except RuntimeError as error:
            raise CommandError(str(error)) from None
    return _report(result, task, out, node_values)


def _start(core: Any) -> dict[str, Any]:
    """Return the starting point: the flat values that differ from the defaults."""
    from mlsemreg_ros.core.config import RegistrationConfig

    defaults = RegistrationConfig().to_flat_dict()
    return {k: v for k, v in core.to_flat_dict().items() if v != defaults[k]}


def _evaluator(
    objective: str, data: Path, descriptor: str, bounds: Any, stride: int, max_frames: Any
) -> Any:
    from mlsemreg_ros.datasets.pairs import list_pairs
    from mlsemreg_ros.evaluation.tuning import BagEvaluator, PairsEvaluator

    if objective == 'pairs':
        if not data.is_dir() or not list_pairs(data):
            raise CommandError(f'no pair files (*.npz) in {data}', 2)
        return PairsEvaluator(data, descriptor, bounds)
    return BagEvaluator(data, bounds, stride, max_frames)


def _measure_kiss_icp(task: Any, quiet: bool) -> None:
    """KISS-ICP's latency on the bag, once per study (kept as a study attribute)."""
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.tuning import open_storage
    import optuna

    study = optuna.load_study(study_name=task.study_name, storage=open_storage(task.storage))
    latency = study.user_attrs.get('kiss_latency_ms_p50')
    if latency is None:
        if not quiet:
            tables.print_text('measuring KISS-ICP on the same scans (the time reference) ...')
        latency = task.evaluator.measure_kiss_icp()
        study.set_user_attr('kiss_latency_ms_p50', latency)
    task.evaluator.kiss_latency_ms = float(latency)


def _space_table(dims: list[Any], core: Any) -> Any:
    from mlsemreg_ros.evaluation.tables import ResultTable

    flat = core.to_flat_dict()
    rows = [[d.key, d.describe(), str(flat[d.key])] for d in dims]
    return ResultTable(('parameter', 'searched', 'start'), rows, left_columns=3)


class _Progress:
    """A rich progress bar of the study's finished trials (all workers), best loss so far."""

    def __init__(self, total: int | None, quiet: bool, finished_before: int) -> None:
        from mlsemreg_ros.evaluation.tables import console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        self._progress = Progress(
            TextColumn('trials'),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn('{task.fields[status]}'),
            console=console(stderr=True),
            disable=quiet,
        )
        self._task = self._progress.add_task('trials', total=total, status='')
        self._before = finished_before

    def __enter__(self) -> _Progress:
        self._progress.__enter__()
        return self

    def __exit__(self, *args: Any) -> None:
        self._progress.__exit__(*args)

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


def _report(study: Any, task: Any, out: Path, node_values: dict[str, Any]) -> int:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation import tables, tuning
    from mlsemreg_ros.evaluation.reports import write_json
    from mlsemreg_ros.parameter_docs import write_params_file

    trials = study.get_trials(deepcopy=False)
    states: dict[str, int] = {}
    for t in trials:
        states[t.state.name] = states.get(t.state.name, 0) + 1
    tables.print_text(
        f'study {task.study_name!r}: {len(trials)} trials ('
        + ', '.join(f'{n} {s.lower()}' for s, n in sorted(states.items()))
        + ')'
    )
    chosen = tuning.chosen_trial(study)
    tables.print_table(_pareto_table(study, chosen))
    plots = tuning.save_plots(study, out)
    record = {
        'study': task.study_name,
        'storage': task.storage,
        'chosen': chosen.number if chosen is not None else None,
        'pareto': [t.number for t in study.best_trials] if chosen is not None else [],
        'plots': plots,
        'trials': [tuning.trial_summary(t) for t in trials],
    }
    write_json(out.with_name(f'{out.stem}_trials.json'), record)
    for name, where in plots.items():
        tables.print_text(f'{name} plot: {where}')
    if chosen is None:
        raise CommandError(f'no trial completed; nothing written to {out}')
    values = tuning.tuned_values(task, chosen)
    header = [
        f'Parameters of mlsemreg_node tuned by `mlsemreg tune` (study {task.study_name!r},',
        f'trial {chosen.number}: {study.metric_names[0]} {chosen.values[0]:.4g}, '
        f'{study.metric_names[1]} {chosen.values[1]:.4g}; docs/tuning.md).',
        f'Load it with: ros2 run mlsemreg_ros mlsemreg_node --ros-args --params-file {out.name}',
        '[unit, range, choices] as enforced by the parameter descriptors.',
    ]
    write_params_file(out, values, node_values, header)
    start = RegistrationConfig().replace(task.base).to_flat_dict()
    rows = [[k, str(start[k]), str(values[k])] for k in chosen.params]
    tables.print_table(
        tables.ResultTable(('parameter', 'start', f'trial {chosen.number}'), rows, left_columns=3)
    )
    tables.print_text(f'wrote {out}')
    return 0


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


def _pareto_table(study: Any, chosen: Any) -> Any:
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


main = alias(tune, HELP, 'mlsemreg-tune')
