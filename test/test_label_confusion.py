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
"""The labels' confusion tool (scripts/label_confusion.py): counts per class and range band."""

from __future__ import annotations

import importlib
from pathlib import Path
import sys

import numpy as np

SCRIPTS = Path(__file__).resolve().parents[1] / 'scripts'


def _script(name: str):
    """Import a module of scripts/ (they import each other by name)."""
    if str(SCRIPTS) not in sys.path:
        sys.path.insert(0, str(SCRIPTS))
    return importlib.import_module(name)


label_confusion = _script('label_confusion')
label_ir = _script('label_ir')
label_fix_rr = _script('label_fix_rr')


def test_counts_fall_in_their_class_cells_and_range_bands():
    order = list(label_confusion.CLASSES)
    points = np.array([[5.0, 0, 0], [0, 15.0, 0], [-25.0, 0, 0], [30.0, 40.0, 0]])
    truth = np.array([9, 13, 18, 1])
    ours = np.array([9, 15, 18, 0])
    out = label_confusion.confusion_by_band(points, truth, ours)
    assert out.shape == (4, 6, 6)
    assert out.sum() == 4
    assert out[0, order.index(9), order.index(9)] == 1
    assert out[1, order.index(13), order.index(15)] == 1
    assert out[2, order.index(18), order.index(18)] == 1
    assert out[3, order.index(1), order.index(0)] == 1


def test_ids_outside_the_five_classes_count_as_unlabeled():
    points = np.zeros((2, 3))
    out = label_confusion.confusion_by_band(points, np.array([7, 300]), np.array([9, 9]))
    unlabeled, ground = list(label_confusion.CLASSES).index(0), 0
    assert out[0, unlabeled, ground] == 2


def test_the_collapse_maps_learning_ids_onto_the_five_classes():
    labels = np.array([9, 17, 14, 15, 16, 19, 3, 6, 0])
    assert label_ir.collapse(labels).tolist() == [9, 9, 13, 15, 18, 18, 1, 0, 0]


def test_a_fixed_class_takes_its_true_class_and_nothing_else_moves():
    # learning ids: 9 road, 13 building, 15 vegetation, 18 pole, 1 car, 0 unlabeled
    geometric = np.array([13, 15, 9, 18, 13, 1, 15])
    field = np.array([15, 13, 13, 15, 13, 1, 0])

    def fixed(fix: str) -> list[int]:
        return label_fix_rr.fixed_labels(geometric, field, fix).tolist()

    # every point whose true or geometric class is building takes its true class; the
    # point the pair file leaves unlabeled keeps the geometric label
    assert fixed('13') == [15, 13, 13, 18, 13, 1, 15]
    assert fixed('bv') == [15, 13, 9, 18, 13, 1, 15]
    assert fixed('bgnd') == [13, 15, 13, 18, 13, 1, 15]
    assert fixed('bunl') == [13, 15, 9, 18, 13, 1, 15]  # no building left unlabeled here
    assert fixed('pfp') == [13, 15, 9, 15, 13, 1, 15]
    assert fixed('pfn') == [13, 15, 9, 18, 13, 1, 15]  # no true pole here
    missed = label_fix_rr.fixed_labels(np.array([13, 15]), np.array([18, 15]), 'pfn')
    assert missed.tolist() == [18, 15]
    assert fixed('merge') == [15, 15, 9, 18, 15, 1, 15]
    assert fixed('all') == [15, 13, 13, 15, 13, 1, 15]
