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
``mlsemreg chain-pairs DIR OUT --apart K``: pairs K links apart from chained pair files.

When ``pts_dst`` of each pair file is ``pts_src`` of the next (the KITTI dev pairs are
such a chain, about 20 m per link), composing ``trans_gt`` gives real pairs with ground
truth at any multiple of the link distance (:func:`mlsemreg_ros.datasets.pairs.chain_pairs`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError, QuietOption
import typer

HELP = (
    'Write the pairs K links apart of a chain of pair files (pts_dst of one = pts_src of '
    'the next) with the composed ground truth.'
)


def chain_pairs(
    directory: Annotated[
        Path, typer.Argument(metavar='DIR', help='folder of chained pair files (*.npz)')
    ],
    out: Annotated[Path, typer.Argument(help='output folder for the composed pair files')],
    apart: Annotated[int, typer.Option(min=1, help='links between source and target')] = 2,
    reverse: Annotated[
        bool, typer.Option(help='swap source and target (trans_gt inverted)')
    ] = False,
    quiet: QuietOption = False,
) -> int:
    """Compose chained pair files into pairs K links apart (alias mlsemreg-chain-pairs)."""
    from mlsemreg_ros.datasets import pairs as pair_files
    from mlsemreg_ros.evaluation.tables import print_text
    import numpy as np

    try:
        loaded = [pair_files.load_pair(p) for p in pair_files.list_pairs(directory)]
        composed = pair_files.chain_pairs(loaded, apart, reverse)
    except (OSError, ValueError) as error:
        raise CommandError(f'cannot chain the pairs of {directory}: {error}') from None
    if not composed:
        raise CommandError(f'{directory} holds {len(loaded)} pair files; {apart} links need more')
    out.mkdir(parents=True, exist_ok=True)
    for pair in composed:
        pair_files.save_pair(out / f'{pair.name}.npz', pair)
    distances = [float(np.linalg.norm(p.trans_gt[:3, 3])) for p in composed]
    if not quiet:
        print_text(
            f'wrote {len(composed)} pairs {apart} links apart to {out} '
            f'({min(distances):.1f}-{max(distances):.1f} m'
            f'{", reversed" if reverse else ""})'
        )
    return 0


main = alias(chain_pairs, HELP, 'mlsemreg-chain-pairs')
