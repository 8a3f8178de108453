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
The repository stands alone: it cites only its own documentation, and its links resolve.

- No tracked file cites a design or style note, or a folder, outside the repository
  (``DESIGN.md``, ``STYLE.md``, ``../shared``). Reading the real dev pairs from
  ``../shared/data`` is allowed: that is data, found by ``test/dev_pairs.py`` and skipped
  when absent, not a reference a reader must follow. The front page names no path of the
  machine the package was developed on either.
- Every relative link of ``README.md`` and ``docs/*.md`` points to a file of the
  repository, and every ``#anchor`` into one of these pages names one of its headings.
"""

from __future__ import annotations

from pathlib import Path
import re
import shutil
import subprocess

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Pages other branches are writing (linked before they exist); empty when all are merged.
PENDING_PAGES: frozenset[str] = frozenset()

#: Citations of files outside the repository (the data folder ``../shared/data`` is exempt).
OUTSIDE = re.compile(r'DESIGN\.md|STYLE\.md|\bDESIGN\b|\.\./shared(?!/data\b)')
#: A development machine's folders, which the README must not name.
MACHINE_PATH = re.compile(r'(?<![\w.])/work/')
#: Inline links and images ``[text](target)``; reference definitions ``[id]: target``.
LINK = re.compile(
    r'!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)'  # [text](target), ![alt](target)
    r'|^\s*\[[^\]]+\]:\s*(\S+)',  # [id]: target
    re.M,
)
FENCE = re.compile(r'^(```|~~~).*?^\1', re.M | re.S)
CODE_SPAN = re.compile(r'`[^`\n]*`')


def _tracked_files() -> list[Path]:
    if shutil.which('git') and (ROOT / '.git').exists():
        out = subprocess.run(
            ['git', 'ls-files', '-z'], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout
        files = [ROOT / name for name in out.split('\0') if name]
    else:  # an exported tree: everything but build and venv folders
        skip = {'.git', '.venv', 'build', 'install', 'log', 'results', '.cache'}
        files = [
            p for p in ROOT.rglob('*') if p.is_file() and not skip & set(p.relative_to(ROOT).parts)
        ]
    return [p for p in files if p.is_file() and p.suffix not in {'.png', '.jpg', '.npz'}]


def _pages() -> list[Path]:
    return [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]


def _anchor(heading: str) -> str:
    """Return the anchor GitHub gives a heading: lower case, no punctuation, hyphens."""
    text = re.sub(r'[`*]', '', heading.strip().lower())
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub('', page.read_text(encoding='utf-8'))
    headings = re.findall(r'^#{1,6}\s+(.+?)\s*#*\s*$', text, re.M)
    return {_anchor(h) for h in headings}


def _links(page: Path) -> list[str]:
    text = CODE_SPAN.sub('', FENCE.sub('', page.read_text(encoding='utf-8')))
    return [a or b for a, b in LINK.findall(text)]


def outside_citations(text: str) -> list[str]:
    """Return the lines of ``text`` that cite something outside the repository."""
    return [line.strip() for line in text.splitlines() if OUTSIDE.search(line)]


def test_the_pattern_finds_outside_citations_and_spares_data_paths() -> None:
    assert outside_citations('Interface (DESIGN.md section 5)')
    assert outside_citations('see STYLE.md item 1')
    assert outside_citations('RE/TE means over successful pairs (DESIGN §4)')
    assert outside_citations('undefined labels (cf. DESIGN pitfalls)')
    assert outside_citations('the paper ../shared/paper/ml-semreg.tex')
    assert not outside_citations('mlsemreg eval-pairs ../shared/data/kitti_pairs_dev')
    assert not outside_citations("ROOT.parent / 'shared' / 'data' / 'kitti_pairs_dev'")
    assert not outside_citations('the design decisions (docs/architecture.md)')


def test_anchors_are_githubs() -> None:
    assert _anchor("The node's stop under load") == 'the-nodes-stop-under-load'
    assert _anchor('Offline evaluation: `mlsemreg eval-bag`') == (
        'offline-evaluation-mlsemreg-eval-bag'
    )
    assert _anchor('ROS 2 interface of `mlsemreg_node`') == 'ros-2-interface-of-mlsemreg_node'


def test_no_tracked_file_cites_a_file_outside_the_repository() -> None:
    offenders = []
    for path in _tracked_files():
        if path == Path(__file__).resolve():
            continue  # this file names the patterns it looks for
        try:
            text = path.read_text(encoding='utf-8')
        except UnicodeDecodeError:
            continue
        offenders += [f'{path.relative_to(ROOT)}: {line}' for line in outside_citations(text)]
    assert not offenders, 'cite docs/... instead:\n' + '\n'.join(offenders)


def test_the_readme_names_no_machine_path() -> None:
    assert MACHINE_PATH.search('mlsemreg simulate /work/sim/seed0')
    lines = (ROOT / 'README.md').read_text(encoding='utf-8').splitlines()
    assert not [line for line in lines if MACHINE_PATH.search(line)]


def test_the_readme_states_the_ci_test_command() -> None:
    ci = (ROOT / '.ci' / 'run').read_text(encoding='utf-8')
    assert 'make test' in ci
    assert 'make test' in (ROOT / 'README.md').read_text(encoding='utf-8')


@pytest.mark.parametrize('page', _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path) -> None:
    broken = []
    for target in _links(page):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target, re.I):  # http:, https:, mailto:
            continue
        path_part, _, anchor = target.partition('#')
        resolved = (page.parent / path_part).resolve() if path_part else page.resolve()
        name = resolved.relative_to(ROOT).as_posix() if resolved.is_relative_to(ROOT) else None
        if name in PENDING_PAGES and not resolved.exists():
            continue
        if name is None or not resolved.exists():
            broken.append(f'{target}: no such file in the repository')
        elif anchor and resolved.suffix == '.md' and anchor not in _anchors(resolved):
            broken.append(f'{target}: no heading #{anchor} in {name}')
    assert not broken, f'{page.relative_to(ROOT)}:\n' + '\n'.join(broken)
