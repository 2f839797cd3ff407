"""How far ICP between two keyframes' leading edges is off along their baseline.

A leading edge lies on the surface that faces the sonar, so two keyframes that see a
structure from different places register points of it that are each pulled towards their
own viewer; the match then comes out short along the baseline, and the loops that span
long baselines shrink the map. This measures it with the truth: each keyframe's cloud (it
and the two before it, at the true poses, as the SLAM front end builds them) is registered
against the cloud around an older keyframe, ICP started *at the true relative pose*, and
the error along the baseline is binned by baseline length.

    .venv/bin/python -m benchmarks.bench_icp_viewpoint_bias --seed 3 --detector labels
    .venv/bin/python -m benchmarks.bench_icp_viewpoint_bias --seed 3 --detector cfar
    .venv/bin/python -m benchmarks.bench_icp_viewpoint_bias --seed 3 --edge-depth-m 0.15

`--edge-depth-m` moves every leading edge that far further along its beam (towards a
piling's centre) before registration.

Measured 2026-11-30, sixth session (marina, 20 goals, separations 5 / 10 / 20 / 40
keyframes; median error along the baseline in % of it, for baselines 6-10 / 10-15 /
15-25 / 25-60 m, 11-51 pairs each; then least squares over all pairs, which the long
ones dominate):

    seed 3,  labels         -0.13 / -0.12 / -0.20 / -0.14   (-0.38 %)
    seed 3,  cfar           -0.25 / -0.15 / -0.24 / -0.33   (-0.77 %)
    seed 0,  labels         -0.12 / -0.12 / -0.14 / +0.00   (-0.06 %)
    seed 0,  cfar           -0.14 / -0.13 / -0.18 / -0.50   (-1.01 %)
    seed 11, labels         -0.22 / -0.10 / -0.12 / +0.13   (-0.16 %)
    seed 11, cfar           -0.23 / -0.10 / -0.29 / +0.09   (-0.63 %)
    seed 3,  labels, 0.15 m -0.02 / -0.04 / -0.06 / +0.22   (+0.00 %)
    seed 3,  cfar, 0.30 m   -0.07 / -0.05 / -0.07 / +0.27   (-0.04 %)

The CFAR matches come out shorter than the perfect detector's, as the CFAR maps come out
smaller (`bench_slam.py`, `*_slam_map_scale_error_pct`). Moving the edges takes
the bias out of these matches but makes the loops worse (median loop error on perfect
seed 3 0.107 -> 0.174 m at 0.15 m; ATE ratios in `bench_slam.py`), so the slam stage
does not do it.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

BINS_M = ((1, 3), (3, 6), (6, 10), (10, 15), (15, 25), (25, 60))


def along_baseline_errors(inputs: dict, separations: list[int], edge_depth_m: float) -> np.ndarray:
    """(N, 2) baseline length and ICP error along it (m) for keyframe pairs k - s, k."""
    from sonarmap.stages.slam.frontend import _FrontEnd
    from sonarmap.stages.slam.pose_graph import se2_between
    from sonarmap.stages.slam.scan_matching import icp_with_covariance
    from sonarmap.stages.slam.stage import SlamConfig, keyframe_points

    c = SlamConfig()
    kf, features = inputs["keyframes.keyframes"], inputs["features.features"]
    if edge_depth_m:
        i = features.schema.get_field_index("range_m")
        shifted = pc.add(features.column("range_m"), pa.scalar(edge_depth_m))
        features = features.set_column(i, features.schema.field(i), shifted)
    truth = np.column_stack([kf.column(n).to_numpy() for n in ("gt_x_m", "gt_y_m", "gt_yaw_rad")])
    T = np.asarray(inputs["keyframes.sensors"]["horizontal"]["T_base_sonar"], float)
    ids = kf.column("keyframe_id").to_numpy()
    points = keyframe_points(ids, features, T, c.point_resolution_m, c.leading_edge_only)

    front = _FrontEnd(c, points)  # its clouds, assembled at the true poses
    front.est = truth
    cloud = front._cloud

    rows = []
    for s in separations:
        for k in range(s + 3, len(ids), 3):
            t = k - s
            source, target = cloud(range(k - 2, k + 1), k), cloud(range(t - 2, t + 3), t)
            true = se2_between(truth[t], truth[k])
            d = float(np.hypot(true[0], true[1]))
            if len(source) < 30 or len(target) < 30 or d < 1.0:
                continue
            pose, overlap, _, _ = icp_with_covariance(
                source, target, true, c.max_correspondence_m, c.icp_max_iterations,
                c.point_noise_m, None,
            )  # fmt: skip
            if overlap >= 30:
                rows.append((d, (pose[:2] - true[:2]) @ true[:2] / d))
    return np.array(rows).reshape(-1, 2)


def main() -> None:
    from tests.fixtures import simulated_slam_inputs

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--detector", choices=("labels", "cfar"), default="labels")
    parser.add_argument("--separations", default="5,10,20,40", help="keyframes apart")
    parser.add_argument("--edge-depth-m", type=float, default=0.0)
    args = parser.parse_args()
    inputs = simulated_slam_inputs("marina", 20, args.seed, detector=args.detector)
    seps = [int(s) for s in args.separations.split(",")]
    x = along_baseline_errors(inputs, seps, args.edge_depth_m)
    print(f"seed {args.seed}, {args.detector}, edge depth {args.edge_depth_m} m: {len(x)} pairs")
    for lo, hi in BINS_M:
        m = (x[:, 0] >= lo) & (x[:, 0] < hi)
        if m.sum() >= 5:
            rel = 100 * x[m, 1] / x[m, 0]
            print(
                f"  baseline {lo:2d}-{hi:2d} m  n {m.sum():4d}  along median "
                f"{100 * np.median(x[m, 1]):+6.2f} cm  ({np.median(rel):+.3f} % of it)"
            )
    ls = np.sum(x[:, 1] * x[:, 0]) / np.sum(x[:, 0] ** 2)
    print(f"  least squares over all pairs: {100 * ls:+.3f} % of the baseline")
    mid = (x[:, 0] >= 6) & (x[:, 0] < 25)
    figures = {
        "pairs": len(x),
        "along_baseline_median_pct_6_25m": round(float(np.median(100 * x[mid, 1] / x[mid, 0])), 3),
        "along_baseline_least_squares_pct": round(100 * float(ls), 3),
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
