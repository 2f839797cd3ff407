"""Features: CFAR detections on both polar images of every keyframe (paper Sec. IV.C),
with thresholds the recording calibrates.

Paper: each image is searched along range, per beam, by SOCA-CFAR (Ntc = 20 training and
Ngc = 10 guard cells, Pfa = 0.1 in the authors' simulation settings), ANDed with a fixed
intensity threshold; every detected cell is one feature. The authors set the CFAR Pfa,
the threshold and a fastNlMeans denoising by hand, differently for simulated and real data
(docs/authors-code.md section 2.2).

Here the same detector runs with thresholds measured from the recording, per sonar and
per range band (`sonarmap.stages.features.calibration`, `sonarmap.stages.kernels.clutter`):

1. calibration: from the `keyframes.calibration_pairs` ping pairs nearest to the ticks of
   a grid of absolute ping time, which stage `keyframes` decodes beside the keyframes
   (`sonarmap.stages.kernels.time_grid`: a power-of-two period, the ticks covering the
   first half to all of the recording; the sample does not depend on the keyframe
   selection, so a spacing sweep calibrates once, and extending or trimming a recording
   at its end keeps it and every keyframe's cached detections), each band's background
   is fitted with a Weibull law over its 60-95 %
   quantiles (objects are the upper tail and move no fit while they fill < 5 % of a band);
   where the unfiltered background puts the floor of step 2 at full scale in most bands
   (a spiky sensor), a 3x3 mean is applied first (`features.denoise: auto`; the authors
   used fastNlMeans on real images);
2. the intensity floor of a band is the smallest level whose exceedance under that law is
   at most the stated per-cell false-alarm rate (`features.false_alarm_rate_per_cell`,
   1e-3), its level set so that the sampled background bands detect that rate; this
   replaces the fixed floor of 20 levels, which floods a real Oculus image (background
   median 43) and is meaningless on an ARIS one (89);
3. SOCA-CFAR stays the local detector (it keeps the leading edge of extended returns, as
   in the paper), its threshold factor calibrated so that the local test alone has
   Pfa = `features.pfa` (0.1) under the fitted law (Monte Carlo, fixed seed) instead of the
   exponential model's closed form, which suits neither a spiky (shape 1.2) nor a flat
   (shape 3.4) background;
4. a per-image feature budget keeps the strongest detections and warns when it clips.

The measurements that decided the law, the filter and the rules: docs/front-end.md.
Any value can be pinned in config (a pinned value is reported as pinned); the old fixed
front end is `intensity_floor: 20, threshold_factor: exponential`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.features import FEATURES_SCHEMA, SONARS
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.base import UNITS_INPUT, Input, StageInputError, Units
from sonarmap.stages.features import STAGE
from sonarmap.stages.features.calibration import (
    calibrate_sample,
    calibration_sample,
    with_measurements,
    with_pinned_bands,
)
from sonarmap.stages.features.config import FeaturesConfig
from sonarmap.stages.features.units import (
    cached_calibration,
    cached_detections,
    detection_base,
)
from sonarmap.stages.kernels.frame_features import detect_ping, keyframe_features
from sonarmap.stages.kernels.front_end import UnmodelableImages, thresholds

__all__ = [
    "STAGE",
    "FeaturesConfig",
    "detect_ping",
    "features_and_calibration",
    "features_table",
    "keyframe_features",
]


def features_and_calibration(
    frames: Sequence[KeyframeImages],
    config: FeaturesConfig,
    units: Units | None = None,
    t_ns: np.ndarray | None = None,
    sample: Sequence[KeyframeImages] | None = None,
) -> tuple[pa.Table, dict[str, Any]]:
    """`features.parquet` and `calibration.json` for a sequence of keyframes: calibrated on
    `sample` (stage `keyframes`' calibration pairs; None: a sample of the keyframes on the
    same time grid), then detected one keyframe in memory at a time, or taken from
    `units`, the engine's per-keyframe memo (`sonarmap.stages.features.units`); `t_ns`:
    the frames' ping times when known without reading them.

    Raises:
        ValueError: keyframe ids not strictly increasing.
        UnmodelableImages: a sonar's images cannot be modelled and a threshold is measured.
    """
    picked = list(sample) if sample is not None else calibration_sample(frames, t_ns)
    doc = cached_calibration(picked, config, STAGE.name, STAGE.version, calibrate_sample, units)
    if config.pinned_bands is not None:
        doc = with_pinned_bands(doc, config.pinned_bands)
    th = thresholds(doc)
    base = detection_base(STAGE.name, STAGE.version, config, th)
    chunks: list[dict[str, np.ndarray]] = []
    n_feat = dict.fromkeys(SONARS, 0)
    clipped = {s: [0, 0] for s in SONARS}
    band_det: dict[str, np.ndarray] = {}
    band_rows: dict[str, np.ndarray] = {}
    last = -1
    for frame in frames:
        if frame.keyframe_id <= last:
            raise ValueError(f"features: keyframe ids must increase, got {frame.keyframe_id}")
        last = frame.keyframe_id
        cols, found = cached_detections(frame, config, th, base, units)
        chunks.append(cols)
        for i, s in enumerate(SONARS):
            n_feat[s] += int(np.count_nonzero(cols["sonar_index"] == i))
            clipped[s][0] += found.dropped[s] > 0
            clipped[s][1] += found.dropped[s]
            band_det[s] = band_det.get(s, 0) + found.band_detections[s]
            band_rows[s] = band_rows.get(s, 0) + found.band_rows[s]
    doc = with_measurements(
        doc, len(chunks), n_feat, band_det, band_rows,
        {s: (c[0], c[1]) for s, c in clipped.items()}, config.max_features_per_keyframe_per_sonar,
    )  # fmt: skip
    names = [f.name for f in FEATURES_SCHEMA]
    if not chunks:
        return FEATURES_SCHEMA.empty_table(), doc
    cols = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    sonar = pa.DictionaryArray.from_arrays(
        pa.array(cols.pop("sonar_index").astype(np.int32)), pa.array(list(SONARS))
    ).cast(pa.string())
    arrays = [sonar if n == "sonar" else pa.array(cols[n]) for n in names]
    return pa.Table.from_arrays(arrays, schema=FEATURES_SCHEMA), doc


def features_table(frames: Sequence[KeyframeImages], config: FeaturesConfig) -> pa.Table:
    """`features.parquet` alone (`features_and_calibration`)."""
    return features_and_calibration(frames, config)[0]


def _times(keyframes: pa.Table | None, n_frames: int) -> np.ndarray | None:
    """The keyframes' ping times from keyframes.parquet (None: not given, or not one row
    per frame: the frames are read for them)."""
    if keyframes is None or keyframes.num_rows != n_frames:
        return None
    keyframes = keyframes.sort_by("keyframe_id")
    return keyframes.column("t_ns").to_numpy().astype(np.int64)


def run(config: FeaturesConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: {"keyframes.frames": Sequence[KeyframeImages],
    "keyframes.calibration_frames" (the ping pairs calibrated on), optionally
    "keyframes.keyframes" (ids and times) and the engine's "units"} ->
    {"features", "calibration"}; unmodelable images are refused as bad input (exit 2)."""
    frames = inputs["keyframes.frames"]
    t_ns = _times(inputs.get("keyframes.keyframes"), len(frames))
    sample = inputs.get("keyframes.calibration_frames")
    try:
        table, doc = features_and_calibration(frames, config, inputs.get(UNITS_INPUT), t_ns, sample)
    except UnmodelableImages as err:
        raise StageInputError(Input("keyframes", "frames"), str(err)) from err
    return {"features": table, "calibration": doc}
