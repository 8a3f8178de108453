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
Which class's errors cost the registration: ``eval-pairs`` with one class made right.

Runs ``mlsemreg eval-pairs ... --labels geometric`` (every argument after ``--`` is the
command's own) with the geometric labels of the chosen classes replaced by the pair file's
labels collapsed to the five classes geometry can tell (``label_ir.collapse``): every point
whose true class or geometric class is one of ``--fix`` takes its true class (points the
pair file leaves unlabeled keep the geometric label). The pair is still judged as
geometrically labelled (``label_source: geometric``: the trust, the wider tilt check), so
the difference to the plain run is what that class's errors cost, all stages included.

``--fix`` takes collapsed ids (9 ground, 13 building + fence, 15 vegetation, 18 pole +
trunk + sign, 1 vehicle), ``all``, or one of the partial fixes:

- ``bv``: only the building <-> vegetation swaps (true and geometric class both building or
  vegetation) are made right;
- ``bgnd``: only the true building points that the labeler calls ground;
- ``bunl``: only the true building points that the labeler leaves unlabeled;
- ``pfp``: only the false poles (geometric pole / trunk / sign, truly something else);
- ``pfn``: only the missed poles (true pole / trunk / sign, labelled something else);
- ``merge``: no truth at all, building labelled vegetation (one class for both).

Usage (docs/labels.md)::

    PYTHONPATH=$PWD .venv/bin/python scripts/label_fix_rr.py --fix 13 -- \\
        eval-pairs PAIR_DIR --descriptor fpfh --labels geometric --set threads=1
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import Any

from mlsemreg_ros.core.labeling import source as label_source
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from label_ir import collapse

BUILDING, VEGETATION, GROUND, POLE = 13, 15, 9, 18
ALL = (9, 13, 15, 18, 1)


def fixed_labels(geometric: np.ndarray, field: np.ndarray, fix: str) -> np.ndarray:
    """The geometric learning ids ``geometric`` (N,) with ``fix`` made right by ``field``."""
    ours = collapse(np.asarray(geometric).astype(np.int64))
    truth = collapse(np.asarray(field).astype(np.int64))
    out = np.asarray(geometric).astype(np.uint32).copy()
    if fix == 'merge':
        out[ours == BUILDING] = VEGETATION
        return out
    if fix == 'bv':
        chosen = np.isin(truth, (BUILDING, VEGETATION)) & np.isin(ours, (BUILDING, VEGETATION))
    elif fix == 'bgnd':
        chosen = (truth == BUILDING) & (ours == GROUND)
    elif fix == 'bunl':
        chosen = (truth == BUILDING) & (ours == 0)
    elif fix == 'pfp':
        chosen = (ours == POLE) & (truth != POLE) & (truth > 0)
    elif fix == 'pfn':
        chosen = (truth == POLE) & (ours != POLE)
    else:
        classes = ALL if fix == 'all' else tuple(int(c) for c in fix.split(','))
        chosen = (np.isin(truth, classes) | np.isin(ours, classes)) & (truth > 0)
    out[chosen] = truth[chosen]
    return out


def patch(fix: str) -> None:
    """Make ``LabelSource`` hand on the geometric labels with ``fix`` made right."""
    plain = label_source.LabelSource.__call__

    def fixed(self: Any, points: Any, labels: Any, config: Any, intensity: Any = None) -> Any:
        out = plain(self, points, labels, config, intensity)
        if out.source != 'geometric' or labels is None:
            return out
        return label_source.LabeledScan(
            fixed_labels(out.labels, labels, fix), out.source, out.labeling_ms
        )

    label_source.LabelSource.__call__ = fixed


def main() -> None:
    """Patch the label source, then run the mlsemreg command after ``--``."""
    argv = sys.argv[1:]
    if '--' not in argv:
        sys.exit('usage: label_fix_rr.py --fix CLASSES -- eval-pairs DIR ... --labels geometric')
    split = argv.index('--')
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument(
        '--fix', required=True, help='collapsed ids, all, bv, bgnd, bunl, pfp, pfn or merge'
    )
    args = parser.parse_args(argv[:split])
    patch(args.fix)
    from mlsemreg_ros.tools.cli import main as cli

    sys.argv = ['mlsemreg', *argv[split + 1 :]]
    cli()


if __name__ == '__main__':
    main()
