#!/usr/bin/env python3
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
Measure the package's shape: the figures of docs/architecture.md's "Measured shape".

- the largest modules of ``core/`` (lines, as ``wc -l``);
- the longest functions outside ``tools/`` and in ``core/`` (a function's lines from its
  ``def`` to its last line, Python's ``ast``; decorators not counted);
- ``Registration.register`` and ``Odometry.process``, and ``odometry.py``;
- the longest command functions of ``tools/`` (with and without their docstring);
- imports up the layers and import circles (``test/test_imports.py``'s graph and layers).

Usage (from the repository root)::

    PYTHONPATH=$PWD .venv/bin/python scripts/code_shape.py [--top 3]

The walk's returns are ``scripts/walk_returns.py``'s (it replays a bag).
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path
import sys

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / 'mlsemreg_ros'


def functions(path: Path) -> list[tuple[str, int, int]]:
    """Return ``(qualified name, lines, lines after the docstring)`` of every function."""
    tree = ast.parse(path.read_text())
    out: list[tuple[str, int, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f'{prefix}{child.name}'
                lines = child.end_lineno - child.lineno + 1
                body = child.body
                doc = ast.get_docstring(child) is not None
                first = body[1] if doc and len(body) > 1 else body[0]
                out.append((name, lines, child.end_lineno - first.lineno + 1))
                visit(child, f'{name}.')
            elif isinstance(child, ast.ClassDef):
                visit(child, f'{prefix}{child.name}.')

    visit(tree, '')
    return out


def module_lines(folder: Path) -> list[tuple[int, str]]:
    """Return ``(lines, path)`` of every module below ``folder``, longest first."""
    rows = [
        (len(path.read_text().splitlines()), str(path.relative_to(PACKAGE)))
        for path in folder.rglob('*.py')
    ]
    return sorted(rows, reverse=True)


def longest(paths: list[Path], top: int) -> list[tuple[int, int, str]]:
    """Return ``(lines, lines after the docstring, module:function)``, longest first."""
    rows = [
        (lines, body, f'{path.relative_to(PACKAGE)}:{name}')
        for path in paths
        for name, lines, body in functions(path)
    ]
    return sorted(rows, reverse=True)[:top]


def layering() -> tuple[list[str], list[list[str]]]:
    """Return the imports up the layers and the import circles (``test/test_imports.py``)."""
    sys.path.insert(0, str(ROOT / 'test'))
    import test_imports

    graph = test_imports.import_graph()
    layers = test_imports.layers_of(test_imports.ARCHITECTURE.read_text())
    return test_imports.upward_imports(graph, layers), test_imports.cycles(graph)


def main(argv: list[str] | None = None) -> int:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--top', type=int, default=3, help='rows of each list')
    top = parser.parse_args(argv).top
    every = sorted(PACKAGE.rglob('*.py'))
    tools = [p for p in every if p.relative_to(PACKAGE).parts[0] == 'tools']
    core = [p for p in every if p.relative_to(PACKAGE).parts[0] == 'core']
    print('largest modules of core/:')
    for lines, path in module_lines(PACKAGE / 'core')[:top]:
        print(f'  {lines:5d}  {path}')
    outside = [p for p in every if p not in tools]
    for title, paths in (('outside tools/', outside), ('core/', core)):
        print(f'longest functions {title} (lines; after the docstring):')
        for lines, body, name in longest(paths, top):
            print(f'  {lines:5d} ({body})  {name}')
    print('longest functions of tools/ (lines; after the docstring):')
    for lines, body, name in longest(tools, top):
        print(f'  {lines:5d} ({body})  {name}')
    named = (
        ('core/pipeline.py', 'Registration.register'),
        ('core/pipeline.py', 'Registration._run_stages'),
        ('core/odometry/odometry.py', 'Odometry.process'),
    )
    for module, function in named:
        _, lines, body = next(f for f in functions(PACKAGE / module) if f[0] == function)
        size = len((PACKAGE / module).read_text().splitlines())
        print(f'{function}: {lines} lines ({body} after the docstring); {module} {size} lines')
    upward, circles = layering()
    print(f'imports up the layers: {len(upward)}', *upward, sep='\n  ')
    print(f'import circles: {len(circles)}', *circles, sep='\n  ')
    return 0


if __name__ == '__main__':
    sys.exit(main())
