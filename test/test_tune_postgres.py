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
``mlsemreg tune`` with two worker processes on a real PostgreSQL server.

The server is Debian's ``postgresql`` (installed by ``scripts/bootstrap.sh`` when run as
root), initialised in a temporary folder as a non-root user (``nobody`` under root: the
server refuses to run as root), listening on 127.0.0.1 at a free port, and stopped after
the test. Without the package, or without psycopg, the test is skipped with the reason.
"""

from __future__ import annotations

from collections.abc import Iterator
import contextlib
import glob
import json
import os
from pathlib import Path
import shutil
import socket
import subprocess
import tempfile

import pytest
from tune_pairs import write_tiny_pair

optuna = pytest.importorskip('optuna')
pytest.importorskip('psycopg', reason='psycopg (PostgreSQL driver) missing: requirements.txt')

USER = 'mlsemreg'


def _server_bin() -> Path:
    """Return PostgreSQL's bin folder, or skip naming the package to install."""
    found = sorted(glob.glob('/usr/lib/postgresql/*/bin/initdb'))
    if not found:
        pytest.skip(
            'PostgreSQL server not installed: apt-get install postgresql (scripts/bootstrap.sh '
            'does it when run as root)'
        )
    return Path(found[-1]).parent


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


def _as_server_user(args: list[str]) -> list[str]:
    """Run ``args`` as ``nobody`` when we are root (initdb and postgres refuse root)."""
    if os.geteuid() != 0:
        return args
    if shutil.which('runuser') is None:
        pytest.skip('running as root without runuser: cannot start PostgreSQL as a normal user')
    return ['runuser', '-u', 'nobody', '--', *args]


@pytest.fixture(scope='module')
def postgres_url() -> Iterator[str]:
    """Start a fresh PostgreSQL server on 127.0.0.1; yield the ``postgres`` database URL."""
    bin_dir = _server_bin()
    folder = Path(tempfile.mkdtemp(prefix='mlsemreg-pg-'))
    data = folder / 'data'
    if os.geteuid() == 0:
        shutil.chown(folder, 'nobody')
    port = _free_port()
    env = {**os.environ, 'LC_ALL': 'C'}

    def run(*args: str) -> None:
        subprocess.run(
            _as_server_user([str(bin_dir / args[0]), *args[1:]]),
            check=True,
            capture_output=True,
            cwd=folder,
            env=env,
            timeout=120,
        )

    try:
        run('initdb', '-D', str(data), '-U', USER, '--auth=trust', '-E', 'UTF8', '--no-sync')
        options = f'-p {port} -k {folder} -c listen_addresses=127.0.0.1 -c fsync=off'
        run('pg_ctl', '-D', str(data), '-o', options, '-l', str(folder / 'log'), '-w', 'start')
    except subprocess.CalledProcessError as error:
        shutil.rmtree(folder, ignore_errors=True)
        pytest.skip(f'PostgreSQL could not start: {error.stderr.decode(errors="replace")[-300:]}')
    try:
        yield f'postgresql://{USER}@127.0.0.1:{port}/postgres'
    finally:
        with contextlib.suppress(subprocess.SubprocessError):
            run('pg_ctl', '-D', str(data), '-m', 'immediate', '-w', 'stop')
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope='module')
def pair_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small generated pair (tune_pairs.py)."""
    return write_tiny_pair(tmp_path_factory.mktemp('pg_pairs'))


@pytest.mark.slow  # a PostgreSQL server and four trials on two spawned workers (~1 min)
def test_two_workers_tune_on_a_postgresql_server(
    postgres_url: str, pair_dir: Path, tmp_path: Path
) -> None:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.tools import cli

    out = tmp_path / 'tuned.yaml'
    args = ['tune', str(pair_dir), '--trials', '4', '--workers', '2']
    args += ['--storage', postgres_url, '--study', 'pg-test', '--out', str(out), '--quiet']
    args += ['--set', 'fine.pair_method=off', '--set', 'bev_search.enabled=false']
    for item in ('semantic.local_radius=0.3:1.5', 'estimator.graph_size=50:300'):
        args += ['--space', item]
    assert cli.main(args) == 0

    study = optuna.load_study(study_name='pg-test', storage=postgres_url)
    trials = study.get_trials(deepcopy=False)
    assert len(trials) == 4  # the enqueued start (run first, here), then three on the workers
    assert all(t.state.is_finished() for t in trials), [t.state for t in trials]
    workers = {t.user_attrs.get('worker') for t in trials[1:]}
    assert len(workers) == 2, workers  # both worker processes ran trials
    record = json.loads(out.with_name('tuned_trials.json').read_text())
    config = RegistrationConfig.from_yaml(out)  # the best parameter file loads
    chosen = next(t for t in record['trials'] if t['number'] == record['chosen'])
    for key, value in chosen['params'].items():
        assert config.to_flat_dict()[key] == value
