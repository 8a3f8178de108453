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
PNG plots of a sequence evaluation (matplotlib, Agg; no display needed).

Figures are built with :class:`matplotlib.figure.Figure` directly, so no global
backend is switched and nothing needs a display.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Colours of the learning ids 0..19 (SemanticKITTI's palette, RGB 0..1).
CLASS_COLORS = (
    np.array(
        [
            [0, 0, 0],
            [100, 150, 245],
            [100, 230, 245],
            [30, 60, 150],
            [80, 30, 180],
            [0, 0, 255],
            [255, 30, 30],
            [255, 40, 200],
            [150, 30, 90],
            [255, 0, 255],
            [255, 150, 255],
            [75, 0, 75],
            [175, 0, 75],
            [255, 200, 0],
            [255, 120, 50],
            [0, 175, 0],
            [135, 60, 0],
            [150, 240, 80],
            [255, 240, 150],
            [255, 0, 0],
        ],
        dtype=float,
    )
    / 255.0
)


def _figure(
    width: float, height: float, rows: int = 1, cols: int = 1, **kwargs: object
) -> tuple[object, np.ndarray]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout='constrained')
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False, **kwargs)).reshape(-1)
    return fig, axes


def plot_trajectory(
    path: str | Path,
    estimate: np.ndarray,
    ground_truth: np.ndarray | None,
    rejected: np.ndarray | None = None,
    title: str = '',
    extra: dict[str, np.ndarray] | None = None,
    label: str = 'ML-SemReg',
) -> None:
    """
    Top view (x, y) of the estimated trajectory (F, 4, 4) against the ground truth.

    ``rejected`` (F,) bool marks scans whose registration was refused (pose held);
    ``extra`` adds more labeled trajectories (e.g. a baseline).
    """
    fig, (ax,) = _figure(7.5, 7.0)
    if ground_truth is not None:
        ax.plot(
            ground_truth[:, 0, 3],
            ground_truth[:, 1, 3],
            color='0.2',
            lw=2.5,
            ls='--',
            label='ground truth',
        )
    for (name, poses), color in zip(
        (extra or {}).items(), ('tab:orange', 'tab:purple', 'tab:brown'), strict=False
    ):
        ax.plot(poses[:, 0, 3], poses[:, 1, 3], lw=1.5, color=color, label=name)
    ax.plot(estimate[:, 0, 3], estimate[:, 1, 3], color='tab:blue', lw=1.8, label=label)
    ax.plot(estimate[0, 0, 3], estimate[0, 1, 3], 'o', color='tab:green', ms=8, label='start')
    if rejected is not None and np.any(rejected):
        ax.plot(
            estimate[rejected, 0, 3],
            estimate[rejected, 1, 3],
            'x',
            color='tab:red',
            ms=7,
            mew=2,
            label=f'rejected ({int(np.sum(rejected))})',
        )
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.grid(alpha=0.3)
    ax.legend(loc='best')
    ax.set_title(title or 'Trajectory, top view')
    fig.savefig(path, dpi=110)


def plot_errors(
    path: str | Path,
    frames: np.ndarray,
    re_deg: np.ndarray,
    te_cm: np.ndarray,
    success: np.ndarray,
    title: str = '',
    max_re_deg: float = 5.0,
    max_te_cm: float = 60.0,
) -> None:
    """Plot per-frame rotation (deg) and translation (cm) errors on log axes with the bounds."""
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    fig, axes = _figure(10.0, 6.0, rows=2, sharex=True)
    for ax, values, bound, label in (
        (axes[0], re_deg, max_re_deg, 'RE [deg]'),
        (axes[1], te_cm, max_te_cm, 'TE [cm]'),
    ):
        finite = np.isfinite(values)
        shown = np.where(finite, np.maximum(values, 1e-3), np.nan)
        ax.semilogy(frames, shown, '.-', color='tab:blue', lw=0.8, ms=4)
        failed = finite & ~success
        if np.any(failed):
            ax.semilogy(
                frames[failed],
                shown[failed],
                'o',
                color='tab:red',
                ms=6,
                label=f'failed ({int(np.sum(~success))})',
            )
            ax.legend(loc='upper right')
        ax.axhline(bound, color='tab:red', ls='--', lw=1)
        ax.text(
            frames[0] if frames.size else 0,
            bound * 0.85,
            f'success bound {bound:g}',
            va='top',
            color='tab:red',
            fontsize=8,
        )
        ax.set_ylabel(label)
        ax.yaxis.set_major_formatter(FormatStrFormatter('%g'))
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.grid(alpha=0.3, which='both')
    axes[1].set_xlabel('frame (bag index)')
    axes[0].set_title(title or 'Per-frame registration error against the keyframe')
    fig.savefig(path, dpi=110)


def plot_correspondences(
    path: str | Path,
    target_points: np.ndarray,
    source_points: np.ndarray,
    T_gt: np.ndarray,
    source_keypoints: np.ndarray,
    target_keypoints: np.ndarray,
    inliers: np.ndarray,
    title: str = '',
    crop: float = 45.0,
    max_lines: int = 150,
    seed: int = 0,
    target_labels: np.ndarray | None = None,
    source_labels: np.ndarray | None = None,
) -> None:
    """
    Top view of one registered pair with its correspondences.

    The keyframe (target) scan is drawn on the left, the current (source) scan on
    the right, aligned with the ground truth ``T_gt`` (4, 4, source -> target) and
    shifted, so correct correspondences are parallel green lines and wrong ones
    red lines that cross. At most ``max_lines`` of each kind are drawn. Points are
    coloured by class when learning-id labels (N,) are given.
    """
    shift = np.array([2.0 * crop + 10.0, 0.0])
    src = source_points @ T_gt[:3, :3].T + T_gt[:3, 3]
    src_kp = source_keypoints @ T_gt[:3, :3].T + T_gt[:3, 3]
    fig, (ax,) = _figure(13.0, 6.5)
    rng = np.random.default_rng(seed)
    for cloud, labels, offset in (
        (target_points, target_labels, np.zeros(2)),
        (src, source_labels, shift),
    ):
        keep = np.flatnonzero(np.all(np.abs(cloud[:, :2]) < crop, axis=1))
        if keep.size > 40000:
            keep = rng.choice(keep, 40000, replace=False)
        colors = (
            '0.6'
            if labels is None
            else CLASS_COLORS[np.clip(np.asarray(labels)[keep], 0, 19)] * 0.8 + 0.2
        )
        ax.scatter(
            cloud[keep, 0] + offset[0],
            cloud[keep, 1] + offset[1],
            s=1.0,
            c=colors,
            lw=0,
            rasterized=True,
        )
    visible = np.all(np.abs(target_keypoints[:, :2]) < crop, axis=1) & np.all(
        np.abs(src_kp[:, :2]) < crop, axis=1
    )
    for mask, color, name in (
        (inliers, 'tab:green', 'inliers'),
        (~inliers, 'tab:red', 'outliers'),
    ):
        rows = np.flatnonzero(mask & visible)
        if rows.size > max_lines:
            rows = np.sort(rng.choice(rows, max_lines, replace=False))
        xs = np.stack([target_keypoints[rows, 0], src_kp[rows, 0] + shift[0]])
        ys = np.stack([target_keypoints[rows, 1], src_kp[rows, 1] + shift[1]])
        ax.plot(xs, ys, color=color, lw=0.6, alpha=0.7)
        ax.plot([], [], color=color, lw=2, label=f'{name}: {int(mask.sum())} ({rows.size} drawn)')
    ax.set_aspect('equal')
    ax.set_xlim(-crop, shift[0] + crop)
    ax.set_ylim(-crop, crop)
    ax.set_xlabel('x [m]  (left: keyframe scan; right: current scan, aligned by ground truth)')
    ax.set_ylabel('y [m]')
    ax.legend(loc='upper center', ncols=2)
    ax.set_title(title or 'Correspondences (ground-truth inliers green, outliers red)')
    fig.savefig(path, dpi=110)
