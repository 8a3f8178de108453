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
The confidence study: the evidence of right and wrong registrations, side by side.

Registers scan pairs of known outcome with the node's registration (own keypoints and
FPFH, the configured thresholds, so a refused estimate goes on to the BEV search) and
records what the returned pose offers as proof (core/estimation/confidence.py; computed whatever
the thresholds): sparse inliers and inlier ratio, dense overlap and label agreement of
the chosen pose, the fine alignment's inlier share.

Cases (``kind``):

- ``dev``: the real KITTI dev pairs, both directions (should register);
- ``chain-far``: dev-chain scans 80-180 m apart (``dst`` of pair i onto ``dst`` of pair
  j, j - i >= 4; the chain: ``src`` of pair k + 1 is ``dst`` of pair k): no overlap;
- ``chain-40m``, ``chain-60m``: the dev pairs composed two and three links apart, both
  ways (:func:`~mlsemreg_ros.datasets.pairs.chain_pairs`; docs/hard_pairs.md); each also
  gives a ``slide`` row, the verdict on its zero-motion pose (the scans on top of each
  other, ~40 or ~60 m from the truth), which must be refused;
- ``mirror``: a scan mirrored in y onto its pair partner and onto itself: no rigid pose;
- ``labels-20``, ``labels-flip``: a dev pair with one label outside the scheme, and with
  20 % of the source labels replaced at random (should still register);
- ``sim``: simulated drives at strides 1, 10 and 20 (should register).

A registration is *right* when its pose is within RE <= 5 deg, TE <= 0.6 m of the ground
truth (the chain's for ``chain-far``; never for ``mirror``). :func:`run_study` writes
``evidence.csv``, ``evidence.png`` and ``streams.csv`` (the failure cases as scan streams
through the odometry) and returns the text tables.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import Any

from mlsemreg_ros.evaluation.settings import EvaluationConfig
import numpy as np

EVIDENCE = ('num_inliers', 'inlier_ratio', 'overlap', 'label_agreement', 'tilt_deg')


@dataclass
class Case:
    """One registration of known outcome."""

    kind: str
    name: str
    source: tuple[np.ndarray, np.ndarray]  # points, labels
    target: tuple[np.ndarray, np.ndarray]
    T_target_source: np.ndarray | None  # ground truth; None: no rigid pose exists


def _mirrored(points: np.ndarray) -> np.ndarray:
    return points * np.array([1.0, -1.0, 1.0])


def dev_cases(directory: Path, seed: int = 0) -> list[Case]:
    """Cases from the dev pairs: pairs both ways, far chain pairs, mirrors, corrupt labels."""
    from mlsemreg_ros.core.rigid import invert_transform
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair

    pairs = [load_pair(p) for p in list_pairs(directory)]
    rng = np.random.default_rng(seed)
    cases: list[Case] = []
    for p in pairs:
        src, dst = (p.pts_src, p.label_src), (p.pts_dst, p.label_dst)
        cases.append(Case('dev', f'{p.name} src->dst', src, dst, p.trans_gt))
        cases.append(Case('dev', f'{p.name} dst->src', dst, src, invert_transform(p.trans_gt)))
        mirrored_src = (_mirrored(p.pts_src), p.label_src)
        mirrored_dst = (_mirrored(p.pts_dst), p.label_dst)
        cases.append(Case('mirror', f'{p.name} mirror(src)->dst', mirrored_src, dst, None))
        cases.append(Case('mirror', f'{p.name} mirror(dst)->dst', mirrored_dst, dst, None))
        one = np.array(p.label_src, dtype=np.int64)
        one[0] = 20
        cases.append(Case('labels-20', f'{p.name} label 20', (p.pts_src, one), dst, p.trans_gt))
        flipped = np.array(p.label_src, dtype=np.int64)
        hit = rng.random(flipped.size) < 0.2
        flipped[hit] = rng.integers(0, 20, int(hit.sum()))
        cases.append(
            Case('labels-flip', f'{p.name} 20 % flipped', (p.pts_src, flipped), dst, p.trans_gt)
        )
    from mlsemreg_ros.datasets.pairs import chain_pairs

    for apart in (2, 3):
        for reverse in (False, True):
            for c in chain_pairs(pairs, apart, reverse):
                cases.append(
                    Case(
                        f'chain-{20 * apart}m',
                        c.name,
                        (c.pts_src, c.label_src),
                        (c.pts_dst, c.label_dst),
                        c.trans_gt,
                    )
                )
    # the chain: T_dst(k)_dst(k-1) = trans_gt of pair k; poses of the dst scans in dst(0)
    poses = [np.eye(4)]
    for p in pairs[1:]:
        poses.append(poses[-1] @ invert_transform(p.trans_gt))
    for i in range(len(pairs)):
        for j in range(i + 4, len(pairs)):
            T_i_j = invert_transform(poses[i]) @ poses[j]
            a, b = (pairs[i].pts_dst, pairs[i].label_dst), (pairs[j].pts_dst, pairs[j].label_dst)
            cases.append(Case('chain-far', f'{pairs[j].name}->{pairs[i].name}', b, a, T_i_j))
            cases.append(
                Case(
                    'chain-far', f'{pairs[i].name}->{pairs[j].name}', a, b, invert_transform(T_i_j)
                )
            )
    return cases


def sim_cases(
    bag: Path, strides: tuple[int, ...] = (1, 10, 20), per_stride: int = 8
) -> list[Case]:
    """Pairs of a simulated bag ``stride`` scans apart (every scan is read once)."""
    from mlsemreg_ros.core.rigid import invert_transform
    from mlsemreg_ros.datasets.factory import open_scan_source

    source = open_scan_source(bag)
    try:
        scans = {s.index: s for s in source.scans()}
    finally:
        source.close()
    cases: list[Case] = []
    last = max(scans)
    for stride in (s for s in strides if s <= last):  # strides the bag is long enough for
        for start in np.linspace(0, last - stride, per_stride).astype(int):
            a, b = scans[int(start)], scans[int(start) + stride]
            T = invert_transform(a.pose) @ b.pose  # b onto a
            cases.append(
                Case(
                    'sim', f'{bag.name} {start}+{stride}', (b.xyz, b.labels), (a.xyz, a.labels), T
                )
            )
    return cases


def measure(
    cases: list[Case], config: Any, bounds: EvaluationConfig | None = None
) -> list[dict[str, Any]]:
    """
    Register every case; one row of the evidence of the returned pose and its outcome each.

    The registration runs with ``config`` as it is, so a refused estimate goes on to the
    BEV search (core/estimation/bev_search.py) and the row holds the pose finally returned; the
    evidence is computed whatever the thresholds. ``accepted`` is whether ``config``'s
    thresholds accept it (the pipeline's ``success``).
    """
    import dataclasses

    from mlsemreg_ros.core.estimation import confidence
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
    from mlsemreg_ros.core.pipeline import Registration
    from tqdm import tqdm

    registration = Registration(config)
    rows = []
    for case in tqdm(cases, desc='confidence', unit='pair', file=sys.stderr):
        result = registration.register_scans(*case.source, *case.target)
        right = False
        re = te = float('nan')
        if case.T_target_source is not None and np.all(np.isfinite(result.transform)):
            re = rotation_error_deg(result.transform[:3, :3], case.T_target_source[:3, :3])
            te = translation_error_m(result.transform[:3, 3], case.T_target_source[:3, 3])
            right = (bounds or EvaluationConfig()).succeeded(re, te)
        d = result.diagnostics
        fields = [f.name for f in dataclasses.fields(confidence.Evidence)]
        evidence = confidence.Evidence(
            **{k: d[f'confidence_{k}'] for k in fields if f'confidence_{k}' in d}
        )
        reason = confidence.refusal(evidence, config.confidence, config.estimator.min_inliers)
        if d.get('covisible_accepted'):  # accepted where both scans see (covisible_acceptance)
            reason = ''
        if case.kind.startswith('chain-') and case.kind != 'chain-far':
            rows.append(_slide_row(registration, case, result))
        rows.append(
            {
                'kind': case.kind,
                'name': case.name,
                'right': right,
                'accepted': not reason,
                'reason': reason,
                're_deg': re,
                'te_m': te,
                'mode': result.mode,
                **{k: d[f'confidence_{k}'] for k in EVIDENCE},
                'label_ceiling': evidence.label_ceiling,
                'fine_inlier_fraction': d.get('fine_inlier_fraction', float('nan')),
            }
        )
    return rows


def _slide_row(registration: Any, case: Case, result: Any) -> dict[str, Any]:
    """Judge a case's zero-motion pose (``Registration.judge``, its correspondences): a row."""
    from mlsemreg_ros.core.metrics import translation_error_m

    source, target = (
        registration.prepare(points, labels, lazy=True)
        for points, labels in (case.source, case.target)
    )
    evidence, reason = registration.judge(
        source, target, np.eye(4), None, result.source_points, result.target_points
    )
    return {
        'kind': 'slide',
        'name': f'{case.name} zero motion',
        'right': False,
        'accepted': not reason,
        'reason': reason,
        're_deg': float('nan'),
        'te_m': translation_error_m(np.zeros(3), case.T_target_source[:3, 3]),
        'mode': 'judge',
        **{k: getattr(evidence, k) for k in EVIDENCE},
        'fine_inlier_fraction': float('nan'),
    }


def summary_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Per evidence: range over right registrations and the largest of wrong ones."""
    lines = [f'{"evidence":<22} {"right: min / p5":>18} {"wrong: p95 / max":>18}']
    right = [r for r in rows if r['right']]
    wrong = [r for r in rows if not r['right']]
    for key in (*EVIDENCE, 'fine_inlier_fraction'):
        ok = np.array([r[key] for r in right], dtype=float)
        bad = np.array([r[key] for r in wrong], dtype=float)
        ok, bad = ok[np.isfinite(ok)], bad[np.isfinite(bad)]
        left = f'{ok.min():.4g} / {np.percentile(ok, 5):.4g}' if ok.size else '-'
        rest = f'{np.percentile(bad, 95):.4g} / {bad.max():.4g}' if bad.size else '-'
        lines.append(f'{key:<22} {left:>18} {rest:>18}')
    lines.append(
        f'{"kind":<12} {"cases":>5} {"right":>5} {"accepted":>8} '
        f'{"right rejected":>14} {"wrong accepted":>14}'
    )
    for kind in sorted({r['kind'] for r in rows}):
        of_kind = [r for r in rows if r['kind'] == kind]
        lines.append(
            f'{kind:<12} {len(of_kind):>5} {sum(r["right"] for r in of_kind):>5} '
            f'{sum(r["accepted"] for r in of_kind):>8} '
            f'{sum(r["right"] and not r["accepted"] for r in of_kind):>14} '
            f'{sum(r["accepted"] and not r["right"] for r in of_kind):>14}'
        )
    return lines


def stream_cases(directory: Path) -> list[tuple[str, list[tuple[Case, bool]]]]:
    """
    Build the issue's failure cases as scan streams for a fresh odometry (the node's path).

    Each stream is ``(kind, [(case, expected right), ...])``: after a reset the first scan
    (``case.target``) starts the odometry, then ``case.source`` is processed; a degenerate
    stream starts with unusable scans. ``expected right`` marks scans a correct odometry
    publishes (the others must be rejected).
    """
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair

    pairs = [load_pair(p) for p in list_pairs(directory)]
    streams: list[tuple[str, list[tuple[Case, bool]]]] = []
    for case in dev_cases(directory):
        if case.kind in ('chain-far', 'mirror'):
            streams.append((case.kind, [(case, False)]))
    for p in pairs:
        huge = p.pts_src.copy()
        huge[0] = 1e30
        streams.append(
            (
                'huge-point',
                [
                    (
                        Case(
                            'huge-point',
                            p.name,
                            (huge, p.label_src),
                            (p.pts_dst, p.label_dst),
                            p.trans_gt,
                        ),
                        True,
                    )
                ],
            )
        )
        one = np.array(p.label_src, dtype=np.int64)
        one[0] = 20
        streams.append(
            (
                'labels-20',
                [
                    (
                        Case(
                            'labels-20',
                            p.name,
                            (p.pts_src, one),
                            (p.pts_dst, p.label_dst),
                            p.trans_gt,
                        ),
                        True,
                    )
                ],
            )
        )
        tiny = [
            Case(
                'degenerate',
                f'{p.name} {n} points',
                (p.pts_dst[:n], p.label_dst[:n]),
                (p.pts_dst[:n], p.label_dst[:n]),
                None,
            )
            for n in (1, 3, 12)
        ]
        streams.append(
            (
                'degenerate-first',
                [(c, False) for c in tiny]
                + [
                    (
                        Case(
                            'degenerate',
                            p.name,
                            (p.pts_src, p.label_src),
                            (p.pts_dst, p.label_dst),
                            p.trans_gt,
                        ),
                        True,
                    )
                ],
            )
        )
    return streams


def run_streams(
    streams: list[tuple[str, list[tuple[Case, bool]]]],
    config: Any,
    bounds: EvaluationConfig | None = None,
) -> list[dict[str, Any]]:
    """Feed each stream to a fresh :class:`Odometry`; count published and wrong frames."""
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from tqdm import tqdm

    odometry = Odometry(Registration(config))
    out = []
    for kind, stream in tqdm(streams, desc='streams', unit='stream', file=sys.stderr):
        odometry.reset()
        published = wrong = rejected = tried = 0
        for case, expected_right in stream:
            odometry.process(*case.target)  # the keyframe (or an unusable scan)
            step = odometry.process(*case.source)
            tried += 1
            if not step.accepted:
                rejected += 1
                continue
            published += 1
            T, truth = step.relative, case.T_target_source
            right = (
                truth is not None
                and expected_right
                and (bounds or EvaluationConfig()).succeeded(
                    rotation_error_deg(T[:3, :3], truth[:3, :3]),
                    translation_error_m(T[:3, 3], truth[:3, 3]),
                )
            )
            wrong += not right
        out.append(
            {
                'kind': kind,
                'tried': tried,
                'rejected': rejected,
                'published': published,
                'wrong_published': wrong,
            }
        )
    return out


def stream_table(rows: list[dict[str, Any]]) -> list[str]:
    """One line per kind of stream: tried, rejected, published, wrong published."""
    lines = [f'{"case":<18} {"tried":>6} {"rejected":>9} {"published":>10} {"wrong":>6}']
    for kind in dict.fromkeys(r['kind'] for r in rows):
        of_kind = [r for r in rows if r['kind'] == kind]
        keys = ('tried', 'rejected', 'published', 'wrong_published')
        total = {k: sum(r[k] for r in of_kind) for k in keys}
        lines.append(
            f'{kind:<18} {total["tried"]:>6} {total["rejected"]:>9} '
            f'{total["published"]:>10} {total["wrong_published"]:>6}'
        )
    return lines


def plot(rows: list[dict[str, Any]], path: Path, config: Any) -> None:
    """Overlap vs label agreement and inlier ratio, right vs wrong, with the thresholds."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    markers = {
        'dev': 'o',
        'chain-far': 'x',
        'chain-40m': 'P',
        'chain-60m': '*',
        'slide': '1',
        'mirror': 's',
        'labels-20': '^',
        'labels-flip': 'v',
        'sim': 'D',
    }
    for kind, marker in markers.items():
        for good, colour in ((True, 'tab:green'), (False, 'tab:red')):
            chosen = [r for r in rows if r['kind'] == kind and r['right'] == good]
            if not chosen:
                continue
            label = f'{kind}, {"right" if good else "wrong"} ({len(chosen)})'
            left.scatter(
                [r['overlap'] for r in chosen],
                [r['label_agreement'] for r in chosen],
                marker=marker,
                c=colour,
                s=28,
                alpha=0.7,
                label=label,
            )
            right.scatter(
                [max(r['inlier_ratio'], 1e-4) for r in chosen],
                [max(r['num_inliers'], 1) for r in chosen],
                marker=marker,
                c=colour,
                s=28,
                alpha=0.7,
                label=label,
            )
    thresholds = config.confidence
    left.axvline(thresholds.min_overlap, color='k', lw=0.8, ls='--')
    left.axhline(thresholds.min_label_agreement, color='k', lw=0.8, ls='--')
    left.set(
        xlabel='overlap (share of the seen surface)',
        ylabel='label agreement',
        title='dense evidence of the chosen pose',
    )
    right.axvline(max(thresholds.min_inlier_ratio, 1e-4), color='k', lw=0.8, ls='--')
    right.axhline(config.estimator.min_inliers, color='k', lw=0.8, ls='--')
    right.set(
        xscale='log',
        yscale='log',
        xlabel='inlier ratio',
        ylabel='inliers',
        title='sparse evidence (SC2-PCR inliers)',
    )
    right.legend(fontsize=7, loc='lower right')
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_study(
    directory: Path | None,
    bags: list[Path],
    out: Path,
    config: Any,
    bounds: EvaluationConfig | None = None,
) -> list[str]:
    """Measure every case, write the results folder, return the text to print."""
    cases = dev_cases(directory) if directory is not None and directory.is_dir() else []
    for bag in bags:
        cases += sim_cases(bag)
    if not cases:
        raise ValueError('no cases: no dev-pair folder and no bags')
    rows = measure(cases, config, bounds)
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(out / 'evidence.csv', rows)
    plot(rows, out / 'evidence.png', config)
    lines = summary_lines(rows)
    if directory is not None and directory.is_dir():
        streams = run_streams(stream_cases(directory), config, bounds)
        _write_csv(out / 'streams.csv', streams)
        lines += ['', "through the odometry (the node's code path):", *stream_table(streams)]
    return lines


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with open(path, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
