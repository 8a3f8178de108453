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
``mlsemreg params``: write ``config/params.yaml`` and ``docs/parameters.md``.

Both are generated from the config metadata by :mod:`mlsemreg_ros.parameter_docs`;
``--check`` only reports whether they are up to date (exit 1 when not), for CI and hooks.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError
import typer

HELP = 'Write config/params.yaml and docs/parameters.md from the config metadata.'


def params(
    params_file: Annotated[
        Path,
        typer.Option('--params-file', dir_okay=False, help='the node parameter file to write'),
    ] = Path('config/params.yaml'),
    doc: Annotated[
        Path,
        typer.Option('--doc', dir_okay=False, help='the parameter reference page to write'),
    ] = Path('docs/parameters.md'),
    check: Annotated[
        bool, typer.Option('--check', help='write nothing; exit 1 if a file is not up to date')
    ] = False,
) -> int:
    """Regenerate config/params.yaml and docs/parameters.md (alias mlsemreg-params)."""
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.parameter_docs import parameters_page, params_yaml_text

    wanted = {params_file: params_yaml_text(), doc: parameters_page()}
    stale = [
        path for path, text in wanted.items() if not path.exists() or path.read_text() != text
    ]
    if check:
        if stale:
            raise CommandError(
                'not up to date (run mlsemreg params): ' + ', '.join(map(str, stale))
            )
        print_text(f'up to date: {params_file}, {doc}')
        return 0
    for path in stale:
        path.write_text(wanted[path])
        print_text(f'wrote {path}')
    if not stale:
        print_text(f'up to date: {params_file}, {doc}')
    return 0


main = alias(params, HELP, 'mlsemreg-params')
