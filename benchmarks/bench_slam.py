"""slam stage speed and accuracy (issue 7 targets), plus PCM on the real Intel graph.

Targets: at least 20 keyframes per second on the default marina mission (scan matching and
loop-closure search included); ATE (RMSE after SE(2) alignment) of SLAM at most half that
of dead reckoning and at most 0.5 m on the default marina.

The mission is simulated (default marina, 20 goals, seed 0; keyframes every 2 m or 30 deg
of dead reckoning). Horizontal features are the simulator's labelled cells (seafloor
excluded), as a perfect detector would report them (`tests/test_slam.py`). A second
mission uses a low-cost navigation (3 % DVL scale error, 3 deg yaw bias). Timing covers
`STAGE.run` only (all four outputs; trajectory.png is the `figures` stage's since issue 41, the
PNG is in the figures below up to then): the median of `--repeats` runs
(3) on the first seed, wall and CPU time (`time.process_time`); the final JSON gives each
figure beside its goal (`*_goal`: issue 22 asks for >= 100 keyframes/s).

    .venv/bin/python benchmarks/bench_slam.py                # seed 0, low-cost nav, PCM
    .venv/bin/python benchmarks/bench_slam.py --seeds 0,1,2,3,4  # robustness over seeds

Version 9 changed only the trajectory PNG (aligned to the truth, with an error panel), so
these figures stand for it.

Issue 22 (2026-12-01, 2 cores shared under a load of 4-6, so wall times move 2x between
runs; CPU time is the comparable figure): byte-identical fast paths (voxel keys folded
into one int64, the consensus grid dilated by a disk instead of a distance transform, the
lattice scored per (yaw, x) and (yaw, y) pair, keyframe clouds built once per estimate,
out-of-view keyframes skipped in the loop-target search, the sonar filter in Arrow) take
the default marina from 25.1 to 33.3 keyframes per CPU second (x1.33; wall 17.9 -> 24.1;
medians of four invocations each, every one the median of 3 runs, the code before and
after interleaved), with every accuracy figure unchanged to the last digit (seeds 0 and
3, low-cost navigation, PCM on Intel) and the demo's slam files sha256-identical. The
goal, 100 keyframes/s, is not met: of what is left (cProfile of `STAGE.run` on the demo)
kiss-icp's registration takes about a quarter (969 calls: 327 matches, 642
re-registrations), the PNG a seventh, the consensus search and the ICP covariances about
a tenth each, iSAM2's 641 updates a twelfth; reaching it needs fewer ICP calls or iSAM2
updates, which changes the output.

Measured 2026-11-30, fifth session (2 shared cores, slam stage version 8: in the loop
re-registration a loop's covariance is also multiplied by ((4 + d) / (4 + 18))^2, d its
baseline in metres, `loop_baseline_growth_m` 4): `--seeds 0,...,9` ratios 0.293 / 0.217 /
0.442 / 0.463 / 0.068 / 0.177 / 0.127 / 0.402 / 0.229 / 0.134 (sum 2.552, version 7
2.622; every seed under 0.5, SLAM 0.042-0.095 m) at 33-41 keyframes/s, peak RSS 0.88 GB;
low-cost navigation 0.132 (0.146); PCM on Intel passes; pier 0.339 (0.334). Real pipeline,
CFAR features (`sonarmap run --until slam`, seeds 0-4): 0.247 / 0.271 / 0.421 / 0.537 /
0.116 (sum 1.592, version 7 1.664), the stage 26.5-30.7 keyframes/s as the CLI runs it.
Seeds never used for tuning (perfect 10-14 | CFAR features through the test helper,
10-12), version 7 -> 8: 0.300 -> 0.303, 0.435 -> 0.423, 0.442 -> 0.397, 0.193 -> 0.193,
0.400 -> 0.387 | 0.381 -> 0.376, 0.438 -> 0.511, 0.401 -> 0.360: sums 1.770 -> 1.703 |
1.220 -> 1.247, and CFAR seed 11 (dead reckoning 0.107 m, like seed 3's) now misses. Why:
a loop's error grows with the distance between its keyframes, RMS against the truth
0.037 / 0.068 / 0.109 / 0.146 / 0.183 / 0.222 / 0.329 m for baselines 0-5 / 5-10 / ... /
25-30 / 30-40 m (perfect seeds 10-12, 494 loops; perfect 2 / 3 and CFAR 0 / 3: 0.035 ..
0.227 m), while the ICP covariance is flat in it (Spearman rho with the true error 0.11
to 0.18; the baseline's 0.45-0.53). Setting every loop's covariance to its true error
(an oracle) would give 0.297 / 0.295 / 0.494 on perfect seeds 3 / 2 and CFAR seed 3: the
loops' weights matter more than their measurements. Not kept (perfect 3 / 2, CFAR 3 /
0 / 1; version 8 0.463 / 0.442 | 0.537 / 0.247 / 0.271): the baseline model as the whole
covariance (0.02 + 0.005 d m, 0.1 + 0.018 d deg; without the shared-data count, or x4)
0.537 / 0.443 | 0.650 / 0.314 / 0.289, 0.504 / 0.344 | 0.688 / 0.368 / 0.323, 0.600 /
0.644 | 0.655 / 0.303 / 0.288 (the loops' errors are correlated, so their marginal
variances overweight them); the growth's power 1 instead of 2 0.482 / 0.393 | 0.568 /
0.245 / 0.286; covariances from each loop's residual after the solve (floors 3 cm /
0.2 deg, one or two rounds) 0.441 / 0.375 | 0.634 / 0.289 / 0.304 under version 7; ICP
RMSE as a further factor, (rmse / 0.18 m)^2 or ^1, 0.464 / 0.427 | 0.518 / 0.256 / 0.272
(CFAR seed 11 0.514) and 0.463 / 0.419 | 0.529 / 0.248 / 0.267 (0.511); the loops' Cauchy
scale 0.5 / 2 0.472 / 0.419 | 0.610 / 0.273 / 0.282 (0.560) and 0.455 / 0.380 | 0.575 /
0.250 / 0.288 (0.496). Also under
version 7: leading edges at the first cell of a run that reaches half its peak
intensity (rather than the first detection; all 17 sets): perfect sum 2.560, every
perfect seed but 2 (0.502) under 0.5, CFAR sum 1.685 with seed 3 at 0.676; every range
scaled by 1.0015 / 1.003: CFAR seeds 1 / 3 / 4 / 2 0.248 / 0.550 / 0.084 / 0.384 and 0.244
/ 0.599 / 0.079 / 0.455, perfect seeds 3 / 1 0.589 / 0.240 and 0.788 / 0.259. The map's
scale is the sonar's: the benchmark now prints each map's scale error (the similarity fit
against the truth; ATE's rigid fit does not take it out). With CFAR features the maps
come out 0.02-0.25 % small (CLI seeds 0-4: -0.018 / -0.251 / -0.086 / -0.127 / -0.235 %),
with perfect ones -0.08 to +0.16 %; on seed 3, whose dead reckoning is good, 0.15 % of
range scale (4.5 cm at 30 m, under one 5 cm range bin) moves the ratio by 0.05-0.09.
Sixth session: where the small maps come from. Registered from the true relative pose,
two keyframes' leading edges match 0.1-0.3 % short along a 6-25 m baseline, CFAR's more
than the perfect detector's (`bench_icp_viewpoint_bias.py`: each view sees the surface
facing it). Moving every leading edge 0.15 / 0.25 m further along its beam removes that
(0.15 m, perfect seed 3: -0.38 % -> +0.00 %) but the loops get worse (median error 0.107
-> 0.174 m), and so do the ratios: perfect seeds 3 / 2 / 1 0.913 / 0.585 / 0.251 and 1.135
/ 0.782 / 0.379, CFAR seeds 3 / 1 / 11 0.693 / 0.228 / 0.420 and 1.118 / 0.272 / 0.628
(version 8: 0.463 / 0.442 / 0.217 | 0.537 / 0.271 / 0.511), not kept. Stretching the
re-registered loops' translations by 0.2 % instead (every match's: second figures) helps
CFAR and hurts the perfect detector, whose matches are less short: 0.548 / 0.450 / 0.215
| 0.473 / 0.235 / 0.378 and 0.616 / 0.528 / 0.222 | 0.512 / 0.204 / 0.423, not kept (a
fixed correction cannot know the detector). Re-registration that pairs points only when
they were seen from directions within 60 / 40 deg (the same side of a surface; loops
only; 60 deg for every match as well): the loops' RMS error grows (perfect seed 3 0.167
-> 0.193 m), ratios 0.464 / 0.419 / 0.222 | 0.587 / 0.277 / 0.601, 0.465 / 0.518 / 0.249
| 0.572 / 0.302 / 0.630 and 0.518 / 0.427 / 0.254 | 0.637 / 0.317 / 0.579, not kept.
A loop-scale state (every loop reads its translation through one mission-wide factor 1 +
l, prior sigma 0.5 %, in the batch re-solves; with sigma ~0 the factor reproduces version
8): the graph does not find the shortening, l comes out +0.18 to +0.33 % on the perfect
seeds and -0.10 to +0.11 % on the CFAR ones, and the ratios get worse: 0.553 / 0.530 /
0.256 | 0.599 / 0.325 / 0.605 (the loops against the scan-matched chain cannot separate
it from the odometry's scale state), not kept.

Version 7, measured 2026-11-30, fourth session (2 shared cores, slam stage version 7: each loop
re-registration pass also registers every accepted SSM factor again, from the optimised
poses, ICP only with the 0.3 m gate, against five keyframes instead of three,
`ssm_refine_target_frames` 5): `--seeds 0,...,9` ratios 0.321 / 0.254 / 0.369 / 0.504 /
0.074 / 0.187 / 0.160 / 0.397 / 0.225 / 0.131 (SLAM 0.046-0.101 m) at 29-37 keyframes/s,
peak RSS 0.84 GB; low-cost navigation 0.146; PCM on Intel passes. Real pipeline, CFAR
features (`sonarmap run --until slam`, seeds 0-4): 0.247 / 0.294 / 0.407 / 0.597 / 0.119
(version 6: 0.285 / 0.340 / 0.410 / 0.677 / 0.136), the stage 20-27 keyframes/s as the
CLI runs it (seed 0, the default mission: 27). Pier 0.334 (0.344). On CFAR seed 3 the
SSM error (RMS x / y against the truth) falls from 0.060 / 0.087 m to 0.035 / 0.037 m:
the incremental SSM's global search with its 1 m gate against three keyframes leaves
clutter-driven errors several times the odometry's (0.013 / 0.017 m per step). With
perfect features the SSM is already good and the ratios do not move (sum over the ten
seeds 2.644 -> 2.622; CFAR five 1.848 -> 1.664). Seed 3 still misses: 0.504 (0.054 m
against 0.107 m) and 0.597 (0.064 m). Variants on six sets (perfect seeds 3 / 2 / 0,
CFAR 3 / 0 / 1; version 7 0.504 / 0.369 / 0.321 | 0.597 / 0.247 / 0.294), not kept: three
passes 0.503 / 0.367 / 0.322 | 0.604 / 0.259 / 0.297; eight SSM target keyframes 0.504 /
0.368 / 0.327 | 0.609 / 0.246 / 0.292; refined SSM covariance times 0.25 0.539 / 0.406 /
0.334 | 0.600 / 0.250 / 0.295. The odometry read in the navigation frame (the
dead-reckoned displacement rotated only by the heading-bias state, so that a keyframe's
single heading reading, 0.3 deg of white noise, does not rotate its step; the yaw left to
the heading factors; a GTSAM CustomFactor on pose, pose, scale and bias): the lateral
step error falls from 0.018 to 0.014 m on seed 3, but the ratios do not (all 17 sets,
with the SSM refinement: perfect sum 2.611, CFAR 1.704, CFAR seed 3 0.619), not kept.
On top of it (against 0.518 / 0.367 / 0.325 | 0.619 / 0.240 / 0.292): the tight ICP
already in the incremental SSM 0.513 / 0.366 / 0.329 | 0.673 / 0.244 / 0.294; the
refinement from the odometry guess instead of the estimate, 17-set sums 2.598 | 1.734;
loop search range 25 / 20 m (without the SSM refinement) 0.507 / 0.416 / 0.299 | 0.737 /
0.271 / 0.329 and 0.500 / 0.437 / 0.306 | 0.682 / 0.278 / 0.328. Range offsets on every
feature (version 7) show how much the loops' geometry weighs: -0.05 / -0.10 / +0.05 m
give 0.528 / 0.707 / 0.556 on perfect seed 3 and 0.746 / 1.072 / 0.564 on CFAR seed 3,
not kept: the walls' leading edges are short by 0.04-0.13 m head-on, growing with
range, from the seawall's 0.3 m corrugation, for both feature sources, and no constant
suits both. Single settings under version 6 (0.505 / 0.350 / 0.318 | 0.677 / 0.285 /
0.340), none better on all six: SSM off 0.562 / 0.467 / 0.336 | 0.727 / 0.343 / 0.423;
SSM translation covariance x9 / x100 0.553 / 0.405 / 0.358 | 0.728 / 0.284 / 0.330 and
0.540 / 0.446 / 0.386 | 0.664 / 0.302 / 0.340; loop floor 0.15 m / 0.07 m 0.513 / 0.380
/ 0.328 | 0.749 / 0.300 / 0.355 and 0.522 / 0.352 / 0.316 | 0.667 / 0.286 / 0.345; ICP
effective samples 2 / 8 0.507 / 0.361 / 0.345 | 0.750 / 0.310 / 0.332 and 0.568 / 0.375
/ 0.347 | 0.749 / 0.298 / 0.350. Under version 7: larger loop clouds (source and target
keyframes 7 / 9, sharing window 7 / 9) cut the loop error (CFAR seed 0 median 0.099 ->
0.069 m) but not the ratios, 0.499 / 0.359 / 0.326 | 0.587 / 0.277 / 0.277 and 0.506 /
0.367 / 0.327 | 0.596 / 0.276 / 0.286, with a 0.2 m re-registration gate as well 0.505
/ 0.379 / 0.338 | 0.550 / 0.302 / 0.254; the 0.2 m gate alone (all 17 sets) improves
every CFAR seed, 0.242 / 0.266 / 0.362 / 0.569 / 0.102 (sum 1.541), but not the perfect
ones, 0.354 / 0.256 / 0.369 / 0.498 / 0.069 / 0.184 / 0.155 / 0.424 / 0.245 / 0.133 (sum
2.687), nor the pier (0.391) or low-cost navigation (0.157), so it stays 0.3 m (set
`loop_refine_correspondence_m` 0.2 to favour CFAR features); the incremental SSM against five keyframes
0.497 / 0.405 / 0.324 | 0.614 / 0.267 / 0.299, its search window 0.5 m / 3 deg 0.505 /
0.358 / 0.324 | 0.645 / 0.255 / 0.293; the incremental ICP gate 0.5 m 0.498 / 0.367 /
0.324 | 0.599 / 0.255 / 0.309. True measurements for a subset of seed 3's loops (perfect
| CFAR; version 7): all 0.389 | 0.350; baseline under 15 m 0.445 | 0.589, 15-25 m 0.461
| 0.490, over 25 m 0.443 | 0.455; heading change under 45 deg 0.504 | 0.446, over 0.384
| 0.467; true SSM instead 0.519 | 0.600: the loops limit, all of them a little. The last
eight keyframes of seed 3 have no loop
candidate at all (open water to the south-east), and the loops before them reach back
30-40 m.

Version 6 (2026-11-30, second session; 2 shared cores: the odometry
reads the true motion through a per-mission DVL scale error that is a state,
`odom_scale_sigma` 0.02; with it the navigation noise is the sensors' own, odometry
0.0075 m/sqrt(s) and 0.42 deg per step, heading 0.3 deg, where version 5 had 0.05 m and
0.6 deg per step to absorb the scale error; in the loop re-registration a loop's
covariance is multiplied by the number of loops sharing its sonar data,
`loop_shared_window` 5): `--seeds 0,...,9` ratios 0.318 / 0.284 / 0.350 / 0.505 / 0.078 /
0.183 / 0.175 / 0.398 / 0.220 / 0.133 (SLAM 0.048-0.098 m; seeds 7-9 were not looked at
before) at 35-43 keyframes/s; low-cost navigation 0.065 vs 0.44 m (0.147); PCM on Intel
passes. Real pipeline, CFAR features (`sonarmap run --until slam`, seeds 0-4): 0.285 /
0.340 / 0.410 / 0.677 / 0.136, the stage 30-34 keyframes/s as the CLI runs it. Seed 3
(dead reckoning 0.107 m) still misses: 0.505 (0.054 m) and 0.677 (0.073 m; version 5
1.06). Each part alone (perfect seeds 3 / 2 | CFAR seeds 2 / 0 / 1):
version 5 0.727 / 0.464 | 0.482 / 0.470 / 0.471; the sensors' noise without a scale state
(0.02 m per step) 0.538 / 0.505 | 0.470 / 0.501 / 0.575, and seed 4 0.277 -> 0.662 (its
DVL reads 2.7 % short); with the scale state 0.608 / 0.418 | 0.463 / 0.334 / 0.392, seed 4
0.114; plus the sensors' heading and yaw noise 0.566 / 0.357 | 0.389 / 0.306 / 0.361; plus
the shared-data weighting 0.514 / 0.337 | 0.430 / 0.283 / 0.333. Against version 5 every
one of 14 sets improves but the pier (seed 1, default navigation, 26 loops): 0.228 ->
0.344. Diagnostics on seed 3 (loop error medians, clouds from the true poses): ICP
started at the true relative pose 0.084 m, at the estimate 0.108 m; true loop
measurements would give 0.405. A start-independent kernel-correlation registration
(blurred target density, BFGS) is 0.13-0.15 m: the ICP-from-truth figure is optimistic,
and the loops' error is the sonar geometry's. Not kept (seed 3): leading edges moved out
along the beam by r tan(0.5 deg) tan(incidence), for the beam width on oblique walls (the
walls' measured bias, 0.06 m head-on to 0.37 m at 75 deg and 25 m), 0.62; shared-data
weighting also in the incremental phase 0.509; Cauchy 0.5 0.504; scale prior 0.01 0.505;
odometry yaw left to the heading factors (3 deg) 0.514; the viewpoint-gated ICP in the
re-registration (cos 0.7 / 0.5, perfect 3 | CFAR 3 / perfect 2 / CFAR 2) 0.46 | 0.68 /
0.38 / 0.45 and 0.49 | 0.73 / 0.36 / 0.43, at 19-20 keyframes/s. Oracle loops (true
measurements, version 6 weighting) on CFAR seed 3: 0.424. On version 5: each compact
cluster (a piling) replaced by its estimated centre 0.89, or added to it 0.75; the mean
of 7 / 9 / 27 ICP starts in the re-registration 0.73 / 0.71 / 0.69, at 5-16 keyframes/s.

Version 5 (2026-11-30, first session: when the best loop target
fails its checks, the next best from another stretch of the track is tried,
`nssm_fallback_targets` 1): `--seeds 0,1,2,3,4` ratios 0.441 / 0.473 / 0.464 / 0.727 /
0.277 (SLAM 0.082 / 0.145 / 0.077 / 0.078 / 0.171 m vs dead reckoning 0.185 / 0.306 /
0.165 / 0.107 / 0.619 m) at 38-47 keyframes/s; low-cost navigation 0.085 vs 0.44 m
(0.193); PCM on Intel passes. Real pipeline, CFAR features (`sonarmap run --until slam`,
seeds 0 / 1 / 2): 0.470 / 0.471 / 0.482 (0.087, 0.144, 0.079 m); the whole stage as the
CLI runs it, reading its inputs included, 21-27 keyframes/s. Seed 3 was not used to tune
anything and misses: its dead reckoning is unusually good (0.107 m) and SLAM's error
(0.078 m, like the other seeds') does not halve it. On seed 3 every change since version
2 made the ratio worse (0.578, 0.681, 0.726, 0.727), on seed 4 better (0.315, 0.312,
0.279, 0.277). Seeds 5 / 6: 0.243 / 0.242 (0.131 / 0.094 m vs 0.538 / 0.390 m). A
slower bias walk trades seed 3 against seeds 0-2 (perfect seeds 0-4 | CFAR 0-2): 0.01
0.46 / 0.45 / 0.49 / 0.71 / 0.27 | 0.46 / 0.48 / 0.49; 0.005 0.45 / 0.46 / 0.53 / 0.58 /
0.24 | 0.46 / 0.46 / 0.51; a bounded bias (every bias state also held within 0.5 / 1 deg
of the first): 0.49 / 0.47 / 0.53 / 0.64 / 0.29 | 0.47 / 0.47 / 0.49 and 0.48 / 0.45 /
0.53 / 0.63 / 0.25 | 0.49 / 0.48 / 0.51. Fallback targets on seeds 0-2 (perfect |
CFAR): 0 0.469 / 0.481 / 0.488 | 0.482 / 0.472 / 0.537; 1 0.441 / 0.473 / 0.464 | 0.470 /
0.471 / 0.482; 2 0.441 / 0.495 / 0.492 | 0.470 / 0.477 / 0.482. The last keyframes of
CFAR seed 2 had no loop: their
best target (33 m away) failed on overlap or deviation, every time. Gating loop targets
by heading (`nssm_max_heading_change_deg` 90 / 60; perfect seeds 0-4 | CFAR 0-2): 0.49 /
0.39 / 0.44 / 0.72 / 0.27 | 0.43 / 0.42 / 0.64 and 0.45 / 0.41 / 0.54 / 0.72 / 0.28 |
0.48 / 0.46 / 0.81, not kept. Moving every leading-edge point 0.1 / 0.2 m further along
its beam (towards a piling's centre, so arcs seen from opposite sides would meet): worst
1.09 / 1.47 (seed 3), not kept. Loop covariance floor doubled (0.2 m, 1.15 deg): 0.43 /
0.49 / 0.47 / 0.71 / 0.31 | 0.45 / 0.52 / 0.50; Cauchy scale 0.5: 0.45 / 0.56 / 0.53 /
0.58 / 0.33 | 0.44 / 0.46 / 0.48 (seed 3 better, seeds 1 and 2 worse; mean of the eight
0.478 against 0.476), neither kept.

Version 4 (each heading factor measures the yaw through a heading-bias state that follows
a random walk, 0.02 deg/sqrt(s), so the loops can correct the slowly wandering part of
the AHRS error instead of being pinned to
it): `--seeds 0,1,2` ratios 0.469 / 0.481 / 0.488 (0.087/0.185, 0.147/0.306, 0.081/0.165
m) at 39 / 40 / 49 keyframes/s; low-cost navigation 0.085 m vs 0.44 m (0.193); PCM on
Intel passes. Real pipeline (CFAR features): 0.482 / 0.472 / 0.537 (seed 2: 0.089 vs
0.165 m). Worst of the six 0.576 -> 0.537, median 0.508 -> 0.481. Other walks and white
noises (same six sets): walk 0.01 0.47 / 0.46 / 0.52 | 0.45 / 0.47 / 0.54; 0.005 0.46 /
0.45 / 0.57 | 0.47 / 0.46 / 0.56; 0.05 0.49 / 0.53 / 0.52 | 0.51 / 0.49 / 0.57; white
0.3 deg 0.48 / 0.46 / 0.54 | 0.47 / 0.48 / 0.53; 0.7 deg 0.49 / 0.54 / 0.47 | 0.49 / 0.53
/ 0.52; 1 deg 0.46 / 0.52 / 0.55 | 0.49 / 0.51 / 0.51. Without bias states, independent
heading priors of 0.3 / 1 / 2 deg: worst 0.61 / 0.54 / 0.58. With bias states, a loop
re-registration gate of 0.2 / 0.5 m or 3 passes: worst 0.56 / 0.55 / 0.535. Dropping
long-baseline loops before the re-registration (more than 40 / 30 / 25 m, version 3):
worst 0.65 / 0.72 / 0.79: those loops carry the drift correction.

Version 3 (after the incremental run every accepted loop is re-registered from the
optimised poses, ICP only with a 0.3 m gate, and the graph re-solved in batch, twice;
`loop_refine_passes`): default marina ATE SLAM 0.085 m vs dead reckoning 0.185 m (ratio
0.46; version 2: 0.087 m, 0.47; version 1: 0.63); low-cost navigation 0.086 m vs 0.44 m
(0.195; version 2: 0.21).

`--seeds 0,1,2` (slam version 3, 2 shared cores, 31 s in all): ratios 0.460 / 0.489 /
0.576 at 41 / 44 / 51 keyframes/s (version 2: 0.468 / 0.498 / 0.600). Real pipeline (CFAR
features, `sonarmap simulate --seed S`, `sonarmap run --until slam`): 0.429 / 0.527 /
0.558 (0.080/0.185, 0.161/0.306, 0.092/0.165 m; version 2: 0.503 / 0.589 / 0.634). Worst
of the six 0.634 -> 0.576, median 0.546 -> 0.508; loop error RMS falls on every set (e.g.
CFAR seed 1 0.345 -> 0.229 m, 1.21 -> 0.72 deg). The halving is still not robust (seed 2).
True loop measurements (oracle) would give 0.26 / 0.25 on seeds 2 / 1: loop accuracy is
the limit. Tried on version 2 without a robust gain (single runs move by +-0.03 on
tie-breaks alone): point-to-line ICP (isolated loop error 0.19 -> 0.34 m), line-aware ICP
covariance on loops (0.41 / 0.49 / 0.61), fewer or larger loop clouds, nearest target,
distance cap, stronger Cauchy; a viewpoint-gated ICP (pairs only between points seen
from similar directions: the far side of a hull or piling is another surface) halves
the isolated median loop error but drifts from the odometry-guessed initialisation in the
full run (0.73 on seed 0).

Version 3 variants (ratios perfect seeds 0 / 1 / 2 | CFAR seeds 0 / 1 / 2; one run each of
`STAGE.run` with the experimental code, not kept):
- anisotropic per-point sonar noise (range 3 cm, bearing sigma times range, 7 cm voxel
  floor), SE(2) generalized ICP refining the kiss-icp loop pose: bearing 0.5 deg 0.52 /
  0.51 / 0.56 | 0.65 / 0.63 / 0.68; 1 deg 0.54 / 0.48 / 0.55 | 0.67 / 0.66 / 0.68; 2 deg
  worse; also on SSM 0.58 / 0.50 / 0.55 | 0.69 / 0.63 / 0.70; isotropic (same code, no
  bearing term) 0.50 / 0.50 / 0.57 | 0.62 / 0.62 / 0.69. Loop errors grow (CFAR seed 1
  RMS 0.345 -> 0.47 m at 0.5 deg): letting residuals slide along the beam arc frees the
  per-region bias. Down-weighting far points (isotropic sigma growing with range) is worse
  still (worst 0.80 / 0.89 at 0.5 / 1 deg): far points carry the yaw.
- second pass, other settings: gate 0.5 m one pass 0.47 / 0.49 / 0.57 | 0.49 / 0.56 /
  0.59, two passes 0.47 / 0.50 / 0.55 | 0.49 / 0.54 / 0.59, three 0.46 / 0.50 / 0.55 |
  0.50 / 0.53 / 0.59; gate 1 m 0.47 / 0.50 / 0.57 | 0.52 / 0.57 / 0.60; gate 0.2 m two
  passes 0.46 / 0.47 / 0.57 | 0.40 / 0.52 / 0.58; gate 0.3 m, 11 target frames 0.47 /
  0.45 / 0.60 | 0.38 / 0.53 / 0.53; batch re-solve alone, loops unchanged 0.47 / 0.50 /
  0.59 | 0.50 / 0.59 / 0.59.
- second pass with the viewpoint-gated ICP (cos >= 0.7, gate 0.5 m): lowest loop errors
  (CFAR seed 1 RMS 0.20 m) but seed 2 does not follow: 0.43 / 0.48 / 0.62 | 0.48 / 0.53 /
  0.62; cos 0.5 0.45 / 0.47 / 0.61 | 0.46 / 0.52 / 0.62; cos 0.85 0.43 / 0.50 / 0.63 |
  0.49 / 0.52 / 0.70; two passes, gate 0.3 m 0.43 / 0.47 / 0.68 | 0.45 / 0.48 / 0.64.
- extra short-baseline loops in the second pass (nearest older keyframe within 5 m and 45
  deg): accurate (3 cm) but only 0-7 per mission, no change; alone instead of the loops:
  0.70 / 1.14 / 1.14.

Loop de-correlation and calibration (slam version 2, none kept; ratios on marina seeds
0 / 1 / 2 with perfect features | CFAR features; baseline 0.468 / 0.498 / 0.600 | 0.503 /
0.589 / 0.634). Loop errors are correlated over a few keyframes (lag 1: 0.5-0.8, lag 4:
0.1-0.4) and carry a bias per target region (0.1-0.4 m, 0.5-1.5 deg for up to 25
keyframes, e.g. seed 2's last loops to keyframe 0 at 45 m), which no weighting removes.
- at most one loop per target neighbourhood per 3 keyframes: 0.42 / 0.69 / 0.70 | 0.51 /
  0.53 / 0.60; covariance times (1 + loops sharing source frames): 0.47 / 0.48 / 0.70 |
  0.52 / 0.56 / 0.61; all loop covariances x3: 0.48 / 0.47 / 0.64 | 0.52 / 0.59 / 0.62.
- covariance law fitted on seed 0 (whitened error grows with the keyframe distance,
  Spearman 0.2-0.4 on every set, and falls with overlap): (d / 20 m)^0.9: 0.48 / 0.52 /
  0.63 | 0.52 / 0.59 / 0.65; with (200 / overlap)^0.77: 0.50 / 0.46 / 0.63 | 0.54 / 0.56
  / 0.64 (the overlap scale differs between feature sources).
- target diversity (exclude targets near those of the last 4 keyframes' loops): 0.45 /
  0.42 / 0.73 | 0.45 / 0.47 / 0.56 (exclusion 2, 3, 6 alike: seed 2 worse by about 0.1,
  every other set better); with the best target as fallback 0.52 / 0.43 / 0.65 | 0.48 /
  0.51 / 0.54; two loops per keyframe to distinct targets 0.53 / 0.40 / 0.66 | 0.56 /
  0.54 / 0.62 (about 32 keyframes/s).
- viewpoint-gated ICP as a check: from the kiss-icp pose it stays put (median 1 cm, no
  relation to the error); from the odometry guess its disagreement with kiss-icp predicts
  the loop error (Spearman 0.4-0.6 on every set; loops under the median disagreement have
  half the error), but rejecting disagreeing loops (> 0.15 m: 0.42 / 0.63 / 0.96 | 0.53
  / 0.53 / 0.68) or adding the disagreement to the covariance (0.48 / 0.59 / 0.73 | 0.58
  / 0.56 / 0.66) is worse: the inaccurate loops are the long-baseline ones that hold the
  drift. Each figure is one run of `STAGE.run` with the experimental option (code not
  kept) on the inputs of `--seeds 0,1,2` and the CFAR features of `sonarmap run --until slam`.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

KEYFRAMES_PER_S_GOAL = 100.0
"""Issue 22: the slam stage at >= 100 keyframes/s (issue 7 asked for 20)."""

ATE_RATIO_GOAL = 0.5
"""Issue 7: SLAM's ATE at most half that of dead reckoning."""


def similarity_scale(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Scale s of the best similarity fit s R e + t ~ truth (Umeyama): s > 1, map too small."""
    e, t = estimate - estimate.mean(axis=0), truth - truth.mean(axis=0)
    u, sv, vt = np.linalg.svd(t.T @ e)
    d = np.array([1.0, np.sign(np.linalg.det(u @ vt))])
    return float((sv * d).sum() / (e**2).sum())


def _mission(
    label: str, navigation: dict[str, float] | None, seed: int = 0, repeats: int = 1
) -> dict[str, float]:
    from sonarmap.stages.slam.stage import STAGE, SlamConfig
    from tests.fixtures import ate_se2, simulated_slam_inputs

    inputs = simulated_slam_inputs("marina", n_goals=20, seed=seed, navigation=navigation)
    kf = inputs["keyframes.keyframes"]
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = STAGE.run(SlamConfig(), inputs)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    seconds, cpu_seconds = float(np.median(walls)), float(np.median(cpus))

    def xy(table, prefix=""):
        return np.column_stack([table.column(prefix + c).to_numpy() for c in ("x_m", "y_m")])

    truth = xy(kf, "gt_")
    factors = out["factors"]
    kinds = list(
        zip(factors.column("type").to_pylist(), factors.column("status").to_pylist(), strict=True)
    )
    return {
        f"{label}_keyframes": kf.num_rows,
        f"{label}_keyframes_per_s": round(kf.num_rows / seconds, 1),
        # The machine is shared: CPU time is the figure that other load does not move.
        f"{label}_keyframes_per_cpu_s": round(kf.num_rows / cpu_seconds, 1),
        f"{label}_keyframes_per_s_goal": KEYFRAMES_PER_S_GOAL,
        f"{label}_ate_ratio_goal": ATE_RATIO_GOAL,
        f"{label}_ate_dead_reckoning_m": round(ate_se2(xy(kf), truth), 3),
        f"{label}_ate_slam_m": round(ate_se2(xy(out["poses"]), truth), 3),
        f"{label}_ate_ratio": round(ate_se2(xy(out["poses"]), truth) / ate_se2(xy(kf), truth), 3),
        # ATE is rigid: a map scale error of 0.1 % is 3 cm at the marina's edges.
        f"{label}_slam_map_scale_error_pct": round(
            100 * (1 / similarity_scale(xy(out["poses"]), truth) - 1), 3
        ),
        f"{label}_loops_accepted": kinds.count(("loop", "accepted")),
        f"{label}_loops_rejected": kinds.count(("loop", "rejected")),
        f"{label}_ssm_accepted": kinds.count(("ssm", "accepted")),
    }


def _pcm_intel() -> dict[str, object]:
    """PCM on the Intel graph's loops plus 20 % false ones (`tests/test_pcm.py`'s check):
    the shares of true loops kept and false ones rejected, and whether the test's bounds
    hold (noise scale < 0.01, rejected >= 0.95, kept >= 0.90)."""
    from sonarmap.stages.slam.pcm import chain_covariance, robust_noise_scale, windowed_pcm
    from tests.fixtures import INTEL, intel_loops

    if not INTEL.exists():
        return {}
    t0 = time.perf_counter()
    s = intel_loops(INTEL)
    chain = chain_covariance(s.poses, s.odo_cov)
    scale = robust_noise_scale(s.poses, chain, s.src, s.dst, s.z, s.cov, 0.75)
    chain = chain_covariance(s.poses, s.odo_cov * scale)
    accepted = windowed_pcm(s.poses, chain, s.src, s.dst, s.z, s.cov * scale, window_keys=20)
    kept, rejected = float(accepted[s.truth].mean()), 1.0 - float(accepted[~s.truth].mean())
    return {
        "pcm_intel_passes": bool(scale < 0.01 and rejected >= 0.95 and kept >= 0.90),
        "pcm_intel_kept": round(kept, 3),
        "pcm_intel_rejected": round(rejected, 3),
        "pcm_intel_s": round(time.perf_counter() - t0, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--seeds",
        default="0",
        help="comma-separated seeds of the default marina, e.g. 0,1,2 (seed 0 also runs the"
        " low-cost navigation mission and PCM on Intel)",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="timed runs of the stage on the first seed's mission (the median is reported;"
        " the outputs are deterministic, so the other missions run once)",
    )
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    figures: dict[str, object] = {}
    for n, seed in enumerate(seeds):
        label = "marina" if seed == 0 else f"marina_seed{seed}"
        figures.update(_mission(label, None, seed, args.repeats if n == 0 else 1))
    if 0 in seeds:
        lowcost = {"yaw_bias_deg": 3.0, "dvl_scale_error": 0.03}
        figures.update(_mission("marina_lowcost_nav", lowcost))
        figures.update(_pcm_intel())
    ratios = [v for k, v in figures.items() if k.endswith("_ate_ratio") and "lowcost" not in k]
    figures["marina_worst_ate_ratio"] = max(ratios)
    figures["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
