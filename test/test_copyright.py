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
The standard ament copyright test, with an equivalent check where ament_copyright is absent.

ament_copyright has no PyPI wheel; without it, every Python file must start with the
project's Apache-2.0 header (scripts/license_header.txt), which is what ament_copyright
accepts as a copyright notice plus the apache2 license text.
"""

from pathlib import Path

from lint_paths import PATHS, ROOT
import pytest


@pytest.mark.copyright
@pytest.mark.linter
def test_copyright():
    try:
        from ament_copyright.main import main
    except ImportError:
        header = (ROOT / 'scripts' / 'license_header.txt').read_text().strip()
        files = [
            p
            for path in map(Path, PATHS)
            for p in ([path] if path.is_file() else sorted(path.rglob('*.py')))
        ]
        missing = [str(f.relative_to(ROOT)) for f in files if not f.read_text().startswith(header)]
        assert files and not missing, f'files without the license header: {missing}'
    else:
        assert main(argv=[*PATHS, 'test']) == 0, 'Found errors'
