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
What every command of the ``mlsemreg`` CLI shares: options, settings, errors, the runner.

- ``--config`` / ``--set``: :data:`ConfigOption`, :data:`SetOption` and :func:`settings`
  (defaults < parameter file < ``--set``, one validation for every tool);
- one error style: raise :class:`CommandError`; :func:`run` prints
  ``<prog>: error: <message>`` on stderr for it and for usage errors, and returns the
  exit code (2: bad arguments or settings, 1: the work failed);
- :func:`alias`: the ``main`` of the ``mlsemreg-<name>`` alias of a subcommand (setup.py).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import dataclasses
from pathlib import Path
import shutil
import sys
from typing import Annotated, Any, Literal, TypeVar

from mlsemreg_ros.core.config import RegistrationConfig
import typer


def config_choices(key: str) -> Any:
    """``Literal`` of a config parameter's choices: a CLI option never restates them."""
    return Literal[RegistrationConfig.field_of(key).metadata['choices']]


#: Help panels of the options.
DATA, PARAMETERS, OUTPUT = 'Data', 'Parameters', 'Output'

ConfigOption = Annotated[
    Path | None,
    typer.Option(
        '--config',
        metavar='PATH',
        dir_okay=False,
        exists=True,
        rich_help_panel=PARAMETERS,
        help='parameter YAML: the node layout (config/params.yaml) or plain sections',
    ),
]
SetOption = Annotated[
    list[str] | None,
    typer.Option(
        '--set',
        metavar='KEY=VALUE',
        rich_help_panel=PARAMETERS,
        help='override one parameter, e.g. --set semantic.top_k=3 or --set '
        'evaluation.max_rotation_deg=15 (repeatable; values are YAML)',
    ),
]
LabelsOption = Annotated[
    Literal['field', 'geometric', 'onnx', 'none'] | None,
    typer.Option(
        '--labels',
        rich_help_panel=PARAMETERS,
        help="where the scans' labels come from: the cloud's label field, the built-in "
        'geometric labeler, the ONNX network, or none (the label_source parameter; default: '
        'its value, auto = the field when present, else geometric)',
    ),
]


def with_labels(overrides: Sequence[str] | None, labels: str | None) -> list[str]:
    """``--set`` overrides with ``--labels`` appended as ``label_source`` (it wins)."""
    return [*(overrides or []), *([f'label_source={labels}'] if labels else [])]


QuietOption = Annotated[
    bool, typer.Option('--quiet', help='no progress bar', rich_help_panel=OUTPUT)
]
#: The hidden old spelling of --quiet (kept for the mlsemreg-* aliases).
NoProgressOption = Annotated[
    bool, typer.Option('--no-progress', hidden=True, help='the same as --quiet')
]
#: Where a command writes its results as JSON.
JsonOption = Annotated[
    Path | None,
    typer.Option(
        '--json',
        metavar='PATH',
        dir_okay=False,
        help='write the results as JSON',
        rich_help_panel=OUTPUT,
    ),
]
ForceOption = Annotated[bool, typer.Option('--force', help='replace OUT if it exists')]


def replay_options(scope: str = '') -> tuple[Any, Any]:
    """
    Return ``--stride`` and ``--max-frames`` of a bag replay (evaluation/replay.py).

    One declaration for every command that replays a bag (eval-bag, tune); ``scope``
    prefixes their help (``'bag: '`` where the command also takes other data).
    """
    stride = Annotated[
        int,
        typer.Option(min=1, help=f'{scope}register scan k against k - S', rich_help_panel=DATA),
    ]
    max_frames = Annotated[
        int | None,
        typer.Option(
            min=1, help=f'{scope}stop after this many (strided) scans', rich_help_panel=DATA
        ),
    ]
    return stride, max_frames


#: The bag layout of the bag writers (simulate, kitti-to-bag).
TOPICS = 'Topics and frames'
StorageOption = Annotated[Literal['mcap', 'sqlite3'], typer.Option(help='rosbag2 storage plugin')]
CompressOption = Annotated[
    bool, typer.Option('--compress', help='zstd compression (mcap chunks / sqlite3 messages)')
]
PointsTopicOption = Annotated[
    str, typer.Option(help='topic of the clouds', rich_help_panel=TOPICS)
]
GtTopicOption = Annotated[
    str, typer.Option(help='topic of the ground truth', rich_help_panel=TOPICS)
]
FrameIdOption = Annotated[str, typer.Option(help='frame of the clouds', rich_help_panel=TOPICS)]
WorldFrameOption = Annotated[
    str, typer.Option(help='frame of the ground truth', rich_help_panel=TOPICS)
]


class CommandError(Exception):
    """A command cannot do what it was asked; the message says why (printed by :func:`run`)."""

    def __init__(self, message: str, exit_code: int = 1) -> None:
        """``exit_code`` 2: bad arguments or settings; 1: the work itself failed."""
        super().__init__(message)
        self.message = message
        self.exit_code = exit_code


def configuration_error(error: Exception) -> CommandError:
    """Return the error of invalid settings: ``configuration error: <error>``, exit 2."""
    return CommandError(f'configuration error: {error}', 2)


def settings(
    kinds: tuple[type, ...], config: Path | None, overrides: Sequence[str] | None
) -> tuple[Any, ...]:
    """Load settings of ``kinds``: defaults < ``--config`` < ``--set`` (exit 2 when invalid)."""
    from mlsemreg_ros.core.config import ConfigError, load_settings

    try:
        return load_settings(kinds, config, list(overrides or []))
    except (ConfigError, OSError) as error:
        raise configuration_error(error) from None


OptionsT = TypeVar('OptionsT')


def options_from(context: typer.Context, kind: type[OptionsT], **values: Any) -> OptionsT:
    """
    Build the options dataclass ``kind`` from the command's parsed options of its field names.

    A command then declares its options once (its signature) and hands them to the library
    function as one typed object; ``values`` set or replace fields (converted values).
    """
    names = {field.name for field in dataclasses.fields(kind)}  # type: ignore[arg-type]
    given = {name: value for name, value in context.params.items() if name in names}
    return kind(**{**given, **values})


def require_peers(names: Sequence[str]) -> None:
    """Stop with exit 2 and the install line when a ``--baseline`` peer is not installed."""
    from mlsemreg_ros.evaluation import peer_runs

    try:
        peer_runs.require_peers(list(names))
    except peer_runs.PeerUnavailable as error:
        raise CommandError(str(error), 2) from None


def replace_output(path: Path, force: bool) -> None:
    """Make room for a new output folder; exit 2 if it exists without ``force``."""
    if path.exists():
        if not force:
            raise CommandError(f'{path} exists (use --force to replace it)', 2)
        shutil.rmtree(path)


def _print_error(prog: str, message: str) -> None:
    from mlsemreg_ros.evaluation.tables import console

    console(stderr=True).print(f'{prog}: error: {message}', markup=False, style='red')


def invocation_argv(context: typer.Context) -> list[str]:
    """Return the arguments the command was called with (recorded in result files)."""
    return list((context.find_root().obj or {}).get('argv', sys.argv[1:]))


def run(command: Any, argv: Sequence[str] | None, prog: str) -> int:
    """Run a typer (click) command on ``argv``; return its exit code (one error style)."""
    args = list(argv) if argv is not None else sys.argv[1:]
    try:
        result = command.main(args=args, prog_name=prog, standalone_mode=False, obj={'argv': args})
    except CommandError as error:
        _print_error(prog, error.message)
        return error.exit_code
    except typer.Abort:
        return 130
    except typer.TyperException as error:  # usage errors: unknown option, bad value, ...
        context = getattr(error, 'ctx', None)
        where = context.command_path if context is not None else prog
        message = error.format_message() if hasattr(error, 'format_message') else str(error)
        if message:  # (none when the help was shown for a bare 'mlsemreg')
            _print_error(where, f'{message} (see {where} --help)')
        return int(getattr(error, 'exit_code', 2))
    return result if isinstance(result, int) else 0


def typer_app(**settings: Any) -> typer.Typer:
    """Return a Typer app as every mlsemreg command has it: rich help, ``-h``, no completion."""
    return typer.Typer(
        add_completion=False,
        rich_markup_mode='rich',
        context_settings={'help_option_names': ['-h', '--help']},
        **settings,
    )


def single_command_app(function: Callable[..., int], help_text: str | None = None) -> Any:
    """Build the click command of one subcommand function (its ``mlsemreg-<name>`` alias)."""
    app = typer_app()
    app.command(help=help_text)(function)
    return typer.main.get_command(app)


def alias(
    function: Callable[..., int], help_text: str, prog: str
) -> Callable[[Sequence[str] | None], int]:
    """Return the ``main(argv)`` of the ``mlsemreg-<name>`` alias of a subcommand function."""

    def main(argv: Sequence[str] | None = None) -> int:
        return run(single_command_app(function, help_text), argv, prog)

    main.__doc__ = f'Entry point of ``{prog}`` (the flags of ``mlsemreg {prog[9:]}``).'
    return main
