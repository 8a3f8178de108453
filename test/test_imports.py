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

"""The package's modules import each other without cycles, counting imports inside functions."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

PACKAGE = Path(__file__).resolve().parents[1] / 'mlsemreg_ros'


def _module_name(path: Path, package: Path) -> str:
    parts = path.relative_to(package.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Map each module to the package modules it imports anywhere (functions included)."""
    modules = {_module_name(p, package): p for p in package.rglob('*.py')}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                # ``from package import module`` names a module; otherwise the module itself
                targets = [
                    f'{node.module}.{alias.name}'
                    if f'{node.module}.{alias.name}' in modules
                    else node.module
                    for alias in node.names
                ]
            graph[name] |= {t for t in targets if t in modules and t != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (each an import cycle)."""
    names = sorted(graph)
    index = {n: i for i, n in enumerate(names)}
    rows = [index[a] for a in names for _ in graph[a]]
    cols = [index[b] for a in names for b in graph[a]]
    adjacency = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names),) * 2)
    count, labels = connected_components(adjacency, directed=True, connection='strong')
    groups = [[n for n, g in zip(names, labels, strict=True) if g == k] for k in range(count)]
    return [g for g in groups if len(g) > 1]


def test_the_package_has_no_import_cycle() -> None:
    found = cycles(import_graph())
    assert not found, f'import cycles (imports inside functions count too): {found}'


def test_a_cycle_through_a_function_level_import_is_found(tmp_path: Path) -> None:
    package = tmp_path / 'mlsemreg_ros'
    (package / 'core').mkdir(parents=True)
    (package / '__init__.py').write_text('')
    (package / 'core' / '__init__.py').write_text('')
    (package / 'core' / 'a.py').write_text('from mlsemreg_ros.core import b\n')
    (package / 'core' / 'b.py').write_text('def f():\n    from mlsemreg_ros.core.a import x\n')
    (package / 'core' / 'c.py').write_text('import mlsemreg_ros.core.a\n')
    found = cycles(import_graph(package))
    assert found == [['mlsemreg_ros.core.a', 'mlsemreg_ros.core.b']]
