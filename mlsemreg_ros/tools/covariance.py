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
``mlsemreg covariance-nees``: the NEES of the pose covariance per data set, before and after.

Data sets: the global registrations of pair files (``--pairs``), the pair chain streamed
through the odometry as scans 2 s apart (``--chain``), and bags of drives at strides
(``--drive D --stride S``). "Before" is the Hessian covariance times 7 (the scale before
the ``covariance`` section); "after" is the configuration's calibration. ``--fit`` grid
searches the scale, the floors and the correction terms, without the data sets named by
``--hold-out`` (docs/covariance.md). ``--samples DIR`` keeps the
samples, so a second run (another ``--set``, ``--fit``) does not register again.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import ConfigOption, JsonOption, SetOption, settings
import typer

HELP = 'NEES of the pose covariance on pairs, a pair chain and drives, before and after.'

PairsOption = Annotated[
    Path | None, typer.Option(help='folder of pair files: their global registrations')
]
ChainOption = Annotated[
    Path | None, typer.Option(help='folder of chained pair files, streamed as scans')
]
DriveOption = Annotated[
    list[Path] | None, typer.Option(help='bag of a drive with ground truth (repeatable)')
]
StrideOption = Annotated[
    list[int] | None, typer.Option(help='strides of every drive (repeatable; default 1)')
]
SamplesOption = Annotated[
    Path | None, typer.Option(help='folder to keep the samples in (reused when present)')
]
FitOption = Annotated[bool, typer.Option(help='grid search the calibration')]
ContinuousOption = Annotated[
    bool, typer.Option(help='with --fit: a continuous search (differential evolution)')
]
HoldOutOption = Annotated[
    list[str] | None,
    typer.Option(help='data sets whose name contains this are left out of --fit (repeatable)'),
]


def covariance_nees(
    pairs: PairsOption = None,
    chain: ChainOption = None,
    drive: DriveOption = None,
    stride: StrideOption = None,
    samples: SamplesOption = None,
    fit: FitOption = False,
    continuous: ContinuousOption = False,
    hold_out: HoldOutOption = None,
    config: ConfigOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
) -> int:
    """Print the NEES per data set with the uncalibrated and the configured covariance."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation import covariance_nees as nees
    from mlsemreg_ros.evaluation.reports import write_json

    (core,) = settings((RegistrationConfig,), config, overrides)
    options = nees.NeesOptions(
        pairs,
        chain,
        tuple(drive or ()),
        tuple(stride or [1]),
        samples,
        fit,
        tuple(hold_out or ()),
        continuous,
    )
    result = nees.covariance_nees(options, core)
    nees.print_nees(result)
    if json_path is not None:
        write_json(json_path, result.report)
    return 0
