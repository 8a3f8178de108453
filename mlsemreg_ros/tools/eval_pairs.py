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
``mlsemreg eval-pairs DIR``: register every pair file of a folder, print the paper's table.

The benchmark is :mod:`mlsemreg_ros.evaluation.pairs`; this module is its command line.
Configuration precedence: defaults < ``--config`` YAML < dedicated flags (``--matcher``,
``--no-semantic``, ...) < ``--set section.field=value``. ``--baseline kiss-matcher`` /
``--baseline fpfh-ransac`` (repeatable) run the baselines of
:mod:`mlsemreg_ros.evaluation.baselines` on the same pairs and print RR / RE / TE / time
of every method side by side.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal

from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    config_choices,
    ConfigOption,
    configuration_error,
    JsonOption,
    LabelsOption,
    NoProgressOption,
    options_from,
    PARAMETERS,
    QuietOption,
    SetOption,
    with_labels,
)
import typer


class Baseline(StrEnum):
    """The pair baselines of ``--baseline``."""

    kiss_matcher = 'kiss-matcher'
    fpfh_ransac = 'fpfh-ransac'


BASELINES = tuple(b.value for b in Baseline)
HELP = (
    'Register every pair file (*.npz) of DIR and print the paper metrics (IN, IR under '
    'trans_gt; RE, TE, success within the evaluation bounds, default RE <= 5 deg and '
    'TE <= 60 cm; RR; per-stage times).'
)


def build_settings(
    config_path: Path | None, flags: dict[str, Any], overrides: list[str]
) -> tuple[Any, Any]:
    """
    ``(RegistrationConfig, EvaluationSettings)``: defaults < YAML < ``flags`` < ``--set``.

    Raises ConfigError (a ValueError) with a readable message on bad keys or values.
    """
    from mlsemreg_ros.core.config import apply_overrides, load_settings, RegistrationConfig
    from mlsemreg_ros.evaluation.settings import EvaluationSettings

    core, evaluation = load_settings((RegistrationConfig, EvaluationSettings), config_path)
    if flags:
        core = core.replace(flags)
    return apply_overrides((core, evaluation), overrides)


def build_config(config_path: Path | None, flags: dict[str, Any], overrides: list[str]) -> Any:
    """Build the core part of :func:`build_settings` (``evaluation.*`` keys are rejected)."""
    from mlsemreg_ros.core.config import apply_overrides, RegistrationConfig

    config = (
        RegistrationConfig.from_file(config_path)
        if config_path is not None
        else RegistrationConfig()
    )
    return apply_overrides(config.replace(flags) if flags else config, overrides)


MatcherKind = config_choices('matcher.kind')
EstimatorKind = config_choices('estimator.kind')


DirectoryArgument = Annotated[
    Path,
    typer.Argument(metavar='DIR', help='folder of pair files', exists=True, file_okay=False),
]
DescriptorOption = Annotated[
    Literal['gedi', 'fpfh'],
    typer.Option(
        help='gedi: descriptors stored in the pair files; fpfh: computed at the stored keypoints'
    ),
]
MatcherOption = Annotated[
    MatcherKind | None, typer.Option(help='matcher.kind', rich_help_panel=PARAMETERS)
]
NoSemanticOption = Annotated[
    bool,
    typer.Option(
        '--no-semantic',
        help='plain matcher (the paper baseline): semantic.enabled=false',
        rich_help_panel=PARAMETERS,
    ),
]
EstimatorOption = Annotated[
    EstimatorKind | None,
    typer.Option(help='estimator.kind', rich_help_panel=PARAMETERS),
]
NoRefineOption = Annotated[
    bool,
    typer.Option(
        '--no-refine',
        help='the estimator alone, no fine alignment: fine.pair_method=off',
        rich_help_panel=PARAMETERS,
    ),
]
NoVerificationOption = Annotated[
    bool,
    typer.Option(
        '--no-verification',
        help="keep the estimator's choice: verification.enabled=false",
        rich_help_panel=PARAMETERS,
    ),
]
BaselineOption = Annotated[
    list[Baseline] | None,
    typer.Option(
        help='also run a baseline on the same pairs and compare (repeatable): kiss-matcher '
        '(raw points, voxel 0.3 m, no labels; needs the kiss-matcher package) or fpfh-ransac '
        '(Open3D FPFH + NN + Open3D RANSAC)'
    ),
]
LabelNoiseOption = Annotated[
    str | None,
    typer.Option(
        help='degrade the labels of both scans first: flip:F (a share F of the points get '
        'a uniformly random learning id), confuse:C (a share C of building/vegetation, '
        'road/sidewalk, terrain/vegetation points take the partner class), or both '
        '(flip:0.1,confuse:0.3); seeded by --noise-seed (docs/label_noise.md)'
    ),
]
NoiseSeedOption = Annotated[int, typer.Option(min=0, help='seed of --label-noise')]


def eval_pairs(
    context: typer.Context,
    directory: DirectoryArgument,
    descriptor: DescriptorOption = 'gedi',
    matcher: MatcherOption = None,
    no_semantic: NoSemanticOption = False,
    estimator: EstimatorOption = None,
    no_refine: NoRefineOption = False,
    no_verification: NoVerificationOption = False,
    baseline: BaselineOption = None,
    label_noise: LabelNoiseOption = None,
    noise_seed: NoiseSeedOption = 0,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
    quiet: QuietOption = False,
    no_progress: NoProgressOption = False,
) -> int:
    """Register every pair file of DIR and print the paper metrics (alias mlsemreg-eval-pairs)."""
    from mlsemreg_ros.core.config import ConfigError
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.baselines import BaselineUnavailable
    from mlsemreg_ros.evaluation.label_noise import LabelNoiseError
    from mlsemreg_ros.evaluation.pair_run import evaluate_pairs, PairEvalOptions
    from mlsemreg_ros.evaluation.pairs import EvalError
    from mlsemreg_ros.evaluation.reports import write_json

    flags = _flags(matcher, no_semantic, estimator, no_refine, no_verification)
    try:
        core, evaluation = build_settings(config, flags, with_labels(overrides, labels))
    except (ConfigError, OSError) as error:
        raise configuration_error(error) from None
    peers, progress = tuple(b.value for b in baseline or []), not (quiet or no_progress)
    options = options_from(context, PairEvalOptions, baselines=peers, progress=progress)
    try:
        report = evaluate_pairs(directory, options, core, evaluation.evaluation)
    except LabelNoiseError as error:
        raise CommandError(f'--label-noise: {error}', 2) from None
    except (BaselineUnavailable, EvalError) as error:
        raise CommandError(str(error)) from None
    if json_path is not None:
        write_json(json_path, report)
        tables.print_text(f'wrote {json_path}')
    return 0


def _flags(
    matcher: str | None,
    no_semantic: bool,
    estimator: str | None,
    no_refine: bool,
    no_verification: bool,
) -> dict[str, Any]:
    """Return the flat parameters the shorthand flags set."""
    flags: dict[str, Any] = {}
    if matcher:
        flags['matcher.kind'] = matcher
    if no_semantic:
        flags['semantic.enabled'] = False
    if estimator:
        flags['estimator.kind'] = estimator
    if no_refine:
        flags['fine.pair_method'] = 'off'
    if no_verification:
        flags['verification.enabled'] = False
    return flags


main = alias(eval_pairs, HELP, 'mlsemreg-eval-pairs')
