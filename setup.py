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

"""ament_python package setup for mlsemreg_ros."""

from glob import glob
from pathlib import Path
from xml.etree import ElementTree

from setuptools import find_packages, setup

PACKAGE = 'mlsemreg_ros'
#: The one version source: package.xml (ROS tooling reads it there; bloom bumps it).
VERSION = ElementTree.parse(Path(__file__).resolve().parent / 'package.xml').findtext('version')

setup(
    name=PACKAGE,
    version=VERSION,
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (
            f'share/{PACKAGE}/config',
            glob('config/*.yaml') + glob('config/*.xml') + glob('config/*.rviz'),
        ),
        (f'share/{PACKAGE}/config/labels', glob('config/labels/*.yaml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.launch.py')),
    ],
    install_requires=[
        'setuptools',
        'numpy',
        'scipy',
        'pyyaml',
        'open3d-cpu',
        'tqdm',
        'rosbags',
        'threadpoolctl',
        'small-gicp',
        'numba',
        'matplotlib',
        'typer>=0.29',
        'rich>=13',
        'gtsam>=4.3',
        'optuna>=4',
    ],
    zip_safe=True,
    maintainer='mlsemreg_ros maintainers',
    maintainer_email='maintainers@mlsemreg-ros.invalid',
    description='ML-SemReg + SC2-PCR registration of labeled LiDAR scans, with a ROS 2 node.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'mlsemreg_node = mlsemreg_ros.ros.node:main',
            'mlsemreg_lifecycle_node = mlsemreg_ros.ros.lifecycle_node:main',
            'mlsemreg = mlsemreg_ros.tools.cli:main',
            'mlsemreg-eval-pairs = mlsemreg_ros.tools.eval_pairs:main',
            'mlsemreg-bench = mlsemreg_ros.tools.bench:main',
            'mlsemreg-simulate = mlsemreg_ros.tools.simulate:main',
            'mlsemreg-kitti-to-bag = mlsemreg_ros.tools.kitti_to_bag:main',
            'mlsemreg-eval-bag = mlsemreg_ros.tools.eval_bag:main',
            'mlsemreg-play = mlsemreg_ros.tools.play:main',
            'mlsemreg-demo = mlsemreg_ros.tools.demo:main',
            'mlsemreg-bench-node = mlsemreg_ros.tools.bench_node:main',
            'mlsemreg-confidence = mlsemreg_ros.tools.confidence:main',
            'mlsemreg-soak = mlsemreg_ros.tools.soak:main',
            'mlsemreg-fuzz-node = mlsemreg_ros.tools.fuzz_node:main',
            'mlsemreg-cut-pairs = mlsemreg_ros.tools.cut_pairs:main',
            'mlsemreg-chain-pairs = mlsemreg_ros.tools.chain_pairs:main',
            'mlsemreg-bench-labels = mlsemreg_ros.tools.bench_labels:main',
            'mlsemreg-self-pairs = mlsemreg_ros.tools.self_pairs:main',
            'mlsemreg-label-noise-sweep = mlsemreg_ros.tools.label_noise_sweep:main',
            'mlsemreg-params = mlsemreg_ros.tools.params:main',
            'mlsemreg-relocalize = mlsemreg_ros.tools.relocalize:main',
            'mlsemreg-tune = mlsemreg_ros.tools.tune:main',
        ],
    },
)
