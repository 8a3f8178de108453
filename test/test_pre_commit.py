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

"""The pre-commit hooks (ruff, codespell, end of file, generated parameter docs) pass."""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.linter
def test_pre_commit_hooks_pass_on_every_file(tmp_path: Path) -> None:
    pre_commit = Path(sys.executable).parent / 'pre-commit'
    if not (ROOT / '.git').exists() or not pre_commit.exists() or not shutil.which('git'):
        pytest.skip('needs a git checkout and the venv with pre-commit (make setup)')
    env = dict(os.environ, PRE_COMMIT_HOME=str(tmp_path / 'pre-commit'))
    result = subprocess.run(
        [str(pre_commit), 'run', '--all-files', '--show-diff-on-failure', '--color', 'never'],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
