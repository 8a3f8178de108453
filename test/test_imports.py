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
The package's modules import each other without cycles, and only down the layers.

Imports inside functions count, imports for type checkers only do not. The layer order is
the one written in docs/architecture.md (the block after ``<!-- layers``).
"""

from __future__ import annotations

import ast
from fnmatch import fnmatch
from pathlib import Path
import re

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

PACKAGE = Path(__file__).resolve().parents[1] / 'mlsemreg_ros'
ARCHITECTURE = PACKAGE.parent / 'docs' / 'architecture.md'


def _module_name(path: Path, package: Path) -> str:
    parts = path.relative_to(package.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Map each module to the package modules it imports anywhere (functions included)."""
    modules = {_module_name(p, package): p for p in package.rglob('*.py')}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text())
        for guard in ast.walk(tree):  # imports for type checkers only never run: not counted
            if isinstance(guard, ast.If) and 'TYPE_CHECKING' in ast.unparse(guard.test):
                guard.body = []
        for node in ast.walk(tree):
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
    (package / 'core' / 'a.py').write_text('from mlsemreg_ros.core import b, e\n')
    (package / 'core' / 'b.py').write_text('def f():\n    from mlsemreg_ros.core.a import x\n')
    (package / 'core' / 'c.py').write_text('import mlsemreg_ros.core.a\n')
    (package / 'core' / 'd.py').write_text('from mlsemreg_ros.core import c\n')
    (package / 'core' / 'e.py').write_text(
        'from typing import TYPE_CHECKING\n'
        'if TYPE_CHECKING:\n'
        '    from mlsemreg_ros.core import d\n'
    )
    found = cycles(import_graph(package))
    assert found == [['mlsemreg_ros.core.a', 'mlsemreg_ros.core.b']]


def layers_of(text: str) -> list[tuple[str, list[str]]]:
    """Read ``[(layer, paths)]``, lowest first, from the fenced block after ``<!-- layers``."""
    block = text.split('<!-- layers', 1)[1].split('```', 2)[1]
    found: list[tuple[str, list[str]]] = []
    for line in block.splitlines():
        numbered = re.match(r'\s*\d+\s+(\S+)\s*(.*)', line)
        if numbered:
            found.append((numbered.group(1), numbered.group(2).split()))
        elif line.strip():
            found[-1][1].extend(line.split())  # a continued list of paths
    return found


def _specificity(path: str, pattern: str) -> float:
    """Rate how specifically ``pattern`` names ``path`` (0: not; a file > a glob > a folder)."""
    if pattern.endswith('/'):
        return 1.0 + len(pattern) / 1e3 if path.startswith(pattern) else 0.0
    if '*' in pattern:
        return 2.0 if fnmatch(path, pattern) else 0.0
    return 3.0 if path == pattern else 0.0


def layer_index(module: str, layers: list[tuple[str, list[str]]], package: Path) -> int:
    """Return the index of ``module``'s layer in ``layers`` (ValueError if no layer names it)."""
    parts = module.split('.')[1:]
    path = '/'.join(parts) + '.py'
    if (package / '/'.join(parts) / '__init__.py').is_file():
        path = '/'.join([*parts, '__init__.py'])
    best, index = 0.0, -1
    for i, (_, patterns) in enumerate(layers):
        for pattern in patterns:
            score = _specificity(path, pattern)
            if score > best:
                best, index = score, i
    if index < 0:
        raise ValueError(f'{path}: in no layer of docs/architecture.md')
    return index


def upward_imports(
    graph: dict[str, set[str]], layers: list[tuple[str, list[str]]], package: Path = PACKAGE
) -> list[str]:
    """List every import from a module to a higher layer, as ``'a (layer) -> b (layer)'``."""
    level = {m: layer_index(m, layers, package) for m in graph}
    return sorted(
        f'{a} ({layers[level[a]][0]}) -> {b} ({layers[level[b]][0]})'
        for a, targets in graph.items()
        for b in targets
        if level[b] > level[a]
    )


def test_imports_only_point_down_the_layers_of_the_architecture() -> None:
    layers = layers_of(ARCHITECTURE.read_text())
    assert [name for name, _ in layers][:4] == ['package', 'codec', 'base', 'sections']
    found = upward_imports(import_graph(), layers)
    assert not found, 'imports up the layers (docs/architecture.md):\n' + '\n'.join(found)


def test_an_upward_import_is_found(tmp_path: Path) -> None:
    package = tmp_path / 'mlsemreg_ros'
    (package / 'core' / 'low').mkdir(parents=True)
    (package / '__init__.py').write_text('')
    (package / 'core' / '__init__.py').write_text('')
    (package / 'core' / 'low' / '__init__.py').write_text('')
    (package / 'core' / 'low' / 'config.py').write_text('')
    (package / 'core' / 'low' / 'algo.py').write_text(
        'from mlsemreg_ros.core.low import config\n'
        'def f():\n'
        '    from mlsemreg_ros.core import high\n'
    )
    (package / 'core' / 'high.py').write_text('from mlsemreg_ros.core.low import algo\n')
    text = (
        '<!-- layers -->\n```\n 1 package __init__.py core/__init__.py\n'
        ' 2 sections core/*/config.py\n 3 low core/low/\n 4 high\n   core/high.py\n```\n'
    )
    layers = layers_of(text)
    assert layers[3] == ('high', ['core/high.py'])
    found = upward_imports(import_graph(package), layers, package)
    assert found == ['mlsemreg_ros.core.low.algo (low) -> mlsemreg_ros.core.high (high)']
