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
mlsemreg_node as a child process, and validated settings as its parameter file.

The tools validate ``--config``/``--set`` with the config engine
(:func:`~mlsemreg_ros.core.config.load_settings`) before a node sees them, then hand the
node the effective parameters as one ``--params-file``.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys

from mlsemreg_ros.core.config import NODE_NAME, Settings
import yaml


def write_params_file(path: Path, core: Settings, node: Settings) -> Path:
    """
    Write the node's parameters (core + node settings) as a ``--params-file`` YAML.

    Every value is written typed; YAML 1.1 readers (rcl) keep ``'off'`` a string because the
    dumper quotes it.
    """
    values = {**node.to_dict(), **core.to_dict()}
    path.write_text(yaml.safe_dump({NODE_NAME: {'ros__parameters': values}}, sort_keys=False))
    return path


def start_node(domain_id: int, params_file: Path | None, log: Path) -> subprocess.Popen:
    """Start mlsemreg_node in its own process, with ``params_file`` if given."""
    args = ['--ros-args', '--params-file', str(params_file)] if params_file is not None else []
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    command = [
        sys.executable,
        '-c',
        'import sys; from mlsemreg_ros.ros.node import main; sys.exit(main())',
        *args,
    ]
    return subprocess.Popen(command, env=env, stdout=log.open('w'), stderr=subprocess.STDOUT)


def stop_node(process: subprocess.Popen) -> None:
    """Stop the node with SIGINT (then SIGKILL after 15 s)."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


class NodeProcess:
    """mlsemreg_node in its own process, started again on demand (after a crash)."""

    def __init__(self, domain_id: int, params_file: Path | None, log: Path) -> None:
        """Start the node (:func:`start_node`)."""
        self._start = (domain_id, params_file, log)
        self.process = start_node(*self._start)

    def alive(self) -> bool:
        """Return whether the current process still runs."""
        return self.process.poll() is None

    def restart(self) -> None:
        """Start a new process with the same parameters and log."""
        self.process = start_node(*self._start)

    def stop(self) -> None:
        """Stop the current process (:func:`stop_node`)."""
        stop_node(self.process)
