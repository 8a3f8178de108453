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
``mlsemreg relocalize MAP QUERIES``: relocalize query scans against a map, no initial guess.

The queries, the scoring and the MapClosures comparison are
:func:`mlsemreg_ros.evaluation.relocalization.relocalize_queries`; this module is its
command line (docs/maps.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.evaluation.peer_runs import PlacePeer
from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    configuration_error,
    JsonOption,
    LabelsOption,
    require_peers,
    SetOption,
    with_labels,
)
import typer

HELP = 'Relocalize query scans against a map folder without an initial guess (recall, time).'


MapPathArgument = Annotated[Path, typer.Argument(metavar='MAP', help='map folder (docs/maps.md)')]
QueriesArgument = Annotated[Path, typer.Argument(help='folder of query .npz files')]
MaxQueriesOption = Annotated[int | None, typer.Option(min=1, help='use the first N queries')]
DuplicateOption = Annotated[
    int,
    typer.Option(
        min=1,
        help='scale test: load every keyframe this many times (at the same pose: the '
        'search runs over every copy, map.candidate_separation skips the copies of a '
        'place already tried)',
    ),
]
BaselineOption = Annotated[
    list[PlacePeer] | None,
    typer.Option(help='also relocalize the queries with this peer as place recognition'),
]


def relocalize(
    map_path: MapPathArgument,
    queries: QueriesArgument,
    max_queries: MaxQueriesOption = None,
    duplicate: DuplicateOption = 1,
    baseline: BaselineOption = None,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
) -> int:
    """Relocalize the queries against the map and print the recall (alias mlsemreg-relocalize)."""
    from mlsemreg_ros.core.config import ConfigError
    from mlsemreg_ros.core.maps.map_io import MapError
    from mlsemreg_ros.evaluation.relocalization import (
        print_relocalization,
        QueryError,
        relocalize_queries,
        RelocalizeOptions,
    )
    from mlsemreg_ros.evaluation.reports import write_json

    peers = tuple(str(peer) for peer in baseline or [])
    require_peers(peers)
    options = RelocalizeOptions(max_queries, duplicate, peers)
    try:
        report = relocalize_queries(
            map_path, queries, options, config, with_labels(overrides, labels)
        )
    except ConfigError as error:
        raise configuration_error(error) from None
    except (MapError, QueryError) as error:
        raise CommandError(str(error)) from None
    print_relocalization(report)
    if json_path is not None:
        write_json(json_path, report.as_dict())
    return 0


main = alias(relocalize, HELP, 'mlsemreg-relocalize')
