"""Navigation from what vehicles publish: DVL + IMU + depth dead reckoning with their
mounts, and depth from pressure, a depth field or a pose (a base of `SourceRecording`).

IMU attitude is rotated by the IMU's mount; DVL velocity by the DVL's mount, corrected
for its lever arm with the IMU's angular rate; implausible DVL samples are dropped with
counts per gate; depth comes from `sonarmap.pipeline.readers.depth`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.clock import gap_warning
from sonarmap.pipeline.readers.depth import (
    STANDARD_ATMOSPHERE_PA,
    depth_doubts,
    depth_kind,
    depth_value,
    pressure_depth,
    surface_pressure,
)
from sonarmap.pipeline.readers.dvl import body_velocity, dvl_velocity, gate_velocity
from sonarmap.pipeline.readers.geometry_checks import valid_pose_rows
from sonarmap.pipeline.readers.mounts import SensorGeometry, message_frame
from sonarmap.pipeline.readers.navigation import dead_reckon
from sonarmap.pipeline.readers.navigation_checks import rate_unit_doubt
from sonarmap.pipeline.readers.tf_tree import normalise_frame
from sonarmap.schemas.recording import PoseTrack

__all__ = ["NavigationSensors"]

_ALIGNED = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
"""The default mount of a DVL or IMU: at base_link's origin, aligned with it."""


class NavigationSensors(SensorGeometry):
    """Dead reckoning and depth of a recording (a base of `SourceRecording`)."""

    def _with_depth(self, nav: PoseTrack) -> PoseTrack:
        """The navigation with z from the configured depth topic (when one is set)."""
        if self.roles.depth is None or len(nav) == 0:
            return nav
        t, depth, info = self._depth()
        self._provenance["depth"] = info
        if len(t) == 0:
            return nav
        for line in depth_doubts(t, depth, nav.t_ns):
            self._warn(f"{self.source.path}: {self.roles.depth}: {line}")
        xyz = nav.xyz_m.copy()
        xyz[:, 2] = -np.interp(nav.t_ns, t, depth)
        return PoseTrack(nav.t_ns, xyz, nav.rpy_rad)

    def _dead_reckoning(self) -> PoseTrack:
        """DVL + IMU + depth dead reckoning: IMU attitude rotated by its mount, DVL
        velocity rotated by its mount and corrected for its lever arm, implausible DVL
        samples dropped with counts, depth from pressure, a depth field or a pose."""
        where = str(self.source.path)
        dvl_t, dvl_v, dvl_ok, imu_t, imu_q, imu_w = [], [], [], [], [], []
        frames: dict[str, str] = {}
        topics = [t for t in (self.roles.dvl, self.roles.imu) if t]
        for topic, t, m in self.source.messages(topics):
            if topic not in frames:
                frames[topic] = message_frame(m)
            if topic == self.roles.dvl:
                vx, vy, vz, valid = dvl_velocity(m)
                dvl_t.append(t)
                dvl_v.append((vx, vy, vz))
                dvl_ok.append(valid)
            else:
                imu_t.append(t)
                o, w = m.orientation, m.angular_velocity
                imu_q.append((o.x, o.y, o.z, o.w))
                imu_w.append((w.x, w.y, w.z))
        if not dvl_t or not imu_t:
            raise SourceError(
                f"{where}: DVL {self.roles.dvl} or IMU {self.roles.imu} has no messages"
            )
        assert self.roles.dvl is not None and self.roles.imu is not None
        o = self.options
        base = normalise_frame(o.base_frame)
        T_dvl, dvl_info = self._mount(
            "dvl", frames[self.roles.dvl] or base, o.dvl_mount_xyz_m, o.dvl_mount_rpy_deg, _ALIGNED
        )
        T_imu, imu_info = self._mount(
            "imu", frames[self.roles.imu] or base, None, o.imu_mount_rpy_deg, _ALIGNED, ("rpy",)
        )
        # Bad IMU samples are dropped (DVL samples go through the gates below): a NaN
        # angular rate would move the lever-arm correction as much as a NaN attitude.
        q = np.asarray(imu_q, np.float64).reshape(-1, 4)
        w_all = np.asarray(imu_w, np.float64).reshape(-1, 3)
        ok_q = valid_pose_rows(w_all, q)
        self._drop_warning(self.roles.imu, ok_q)
        q, w_imu, t_imu = q[ok_q], w_all[ok_q], np.asarray(imu_t, np.int64)[ok_q]
        if (doubt := rate_unit_doubt(t_imu, q, w_imu)) is not None:
            self._warn(f"{where}: {self.roles.imu}: {doubt}")
        for topic, times in ((self.roles.imu, t_imu), (self.roles.dvl, dvl_t)):
            gap = gap_warning(f"{where}: {topic}", np.sort(np.asarray(times, np.int64)), "motion")
            if gap:
                self._warn(gap)
        R_bi = T_imu[:3, :3]
        if not np.allclose(R_bi, np.eye(3), atol=1e-12):
            # The IMU reports its own frame's attitude: R_world_base = R_world_imu R_base_imu^T.
            from scipy.spatial.transform import Rotation  # only for a mounted IMU

            q = (Rotation.from_quat(q) * Rotation.from_matrix(R_bi).inv()).as_quat()
        w_base = w_imu @ R_bi.T
        # DVL: gates, then base_link velocity (mount rotation and lever arm).
        t_dvl = np.asarray(dvl_t, np.int64)
        v_dvl = np.asarray(dvl_v, np.float64).reshape(-1, 3)
        gated = gate_velocity(v_dvl, np.asarray(dvl_ok), o.dvl_max_velocity_mps)
        if not gated.keep.any():
            raise SourceError(
                f"{where}: {self.roles.dvl}: none of the {len(t_dvl)} DVL samples is usable ("
                + ", ".join(f"{n} {gate}" for gate, n in gated.dropped.items())
                + "; keyframes.dvl_max_velocity_mps sets the speed limit)"
            )
        if gated.dropped:
            self._warn(
                f"{where}: {self.roles.dvl}: dropped "
                + ", ".join(f"{n} {gate}" for gate, n in gated.dropped.items())
                + f" of {len(t_dvl)} DVL samples (dead reckoning interpolates across them)"
            )
        t_dvl, v_dvl = t_dvl[gated.keep], v_dvl[gated.keep]
        self._check_span(t_dvl, t_imu)
        omega = np.stack([np.interp(t_dvl, t_imu, w_base[:, i]) for i in range(3)], axis=1)
        v_base = body_velocity(v_dvl, T_dvl[:3, :3], T_dvl[:3, 3], omega)
        dep_t, dep, depth_info = self._depth()
        if len(dep_t):
            for line in depth_doubts(dep_t, dep, t_dvl):
                self._warn(f"{where}: {self.roles.depth}: {line}")
        self._provenance["dvl"] = {
            **self._role(self.roles.dvl),
            **dvl_info,
            "max_velocity_mps": o.dvl_max_velocity_mps,
            "dropped": gated.dropped,
        }
        self._provenance["imu"] = {**self._role(self.roles.imu), **imu_info}
        self._provenance["navigation"] = {
            "topic": None,
            "type": None,
            "source": "dead reckoning (DVL, IMU, depth)",
        }
        self._provenance["depth"] = depth_info
        return dead_reckon(t_dvl, v_base, t_imu, q, dep_t, dep, max(o.dvl_max_velocity_mps, 1e9))

    def _check_span(self, t_dvl: np.ndarray, t_imu: np.ndarray) -> None:
        """Refuse DVL samples that span no time inside the IMU's: nothing to integrate."""
        where = f"{self.source.path}: {self.roles.dvl}"
        inside = np.unique(t_dvl[(t_dvl >= t_imu[0]) & (t_dvl <= t_imu[-1])])
        if len(inside) >= 2:
            return
        if len(np.unique(t_dvl)) < 2:
            raise SourceError(
                f"{where}: the DVL has {len(t_dvl)} usable sample(s) at "
                f"{len(np.unique(t_dvl))} distinct time(s); dead reckoning needs at least two "
                "times to integrate the velocity over"
            )
        raise SourceError(
            f"{where}: DVL samples t_ns={int(t_dvl[0])}..{int(t_dvl[-1])} have "
            f"{len(inside)} distinct time(s) inside the IMU {self.roles.imu} span "
            f"t_ns={int(t_imu[0])}..{int(t_imu[-1])}; dead reckoning needs at least two"
        )

    def _drop_warning(self, name: str | None, ok: np.ndarray) -> None:
        if len(ok) and not ok.any():
            raise SourceError(
                f"{self.source.path}: {name}: none of the {len(ok)} samples is finite"
            )
        if not ok.all():
            self._warn(
                f"{self.source.path}: {name}: dropped {len(ok) - int(ok.sum())} of "
                f"{len(ok)} samples (non-finite values or a zero quaternion)"
            )

    def _depth(self) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """(t_ns, depth [m, positive down], provenance) of the depth topic (empty when none)."""
        topic = self.roles.depth
        where = str(self.source.path)
        if topic is None:
            self._warn(
                f"{where}: no depth topic (FluidPressure or a depth message): every pose gets "
                "z = 0; set keyframes.depth_topic"
            )
            empty = np.zeros(0)
            return empty.astype(np.int64), empty, {"topic": None, "source": "default (z = 0)"}
        msgtype = self._types.get(topic, "")
        kind: str | None = None
        t_list: list[int] = []
        values: list[float] = []
        for _, t, m in self.source.messages([topic]):
            if kind is None:
                kind = depth_kind(msgtype, m)
                if kind is None:
                    fields_ = ", ".join(sorted(getattr(m, "__slots__", ()) or vars(m)))[:200]
                    raise SourceError(
                        f"{where}: keyframes.depth_topic: {topic} [{msgtype}] has no depth, "
                        f"fluid_pressure or pose field (fields: {fields_})"
                    )
            t_list.append(t)
            values.append(depth_value(m, kind))
        t_ns = np.asarray(t_list, np.int64)
        raw = np.asarray(values, np.float64)
        ok = np.isfinite(raw)
        self._drop_warning(topic, ok)
        t_ns, raw = t_ns[ok], raw[ok]
        info: dict[str, Any] = {**self._role(topic), "kind": kind or "none"}
        if kind != "pressure" or len(raw) == 0:
            return t_ns, raw, info
        o = self.options
        if o.surface_pressure_pa is not None:
            p0, src = o.surface_pressure_pa, "config"
        elif o.surface_pressure_from_first_s is not None:
            p0, src = surface_pressure(t_ns, raw, o.surface_pressure_from_first_s), "recording"
        else:
            p0, src = STANDARD_ATMOSPHERE_PA, "default"
        info.update(
            surface_pressure_pa=round(p0, 3),
            surface_pressure=src,
            water_density_kg_m3=o.water_density_kg_m3,
            gravity_m_s2=o.gravity_m_s2,
        )
        depth = pressure_depth(raw, p0, o.water_density_kg_m3, o.gravity_m_s2)
        if np.nanmedian(depth) < -5.0 or np.nanmax(np.abs(depth)) > 12_000.0:
            raise SourceError(
                f"{where}: {topic}: fluid_pressure {np.nanmedian(raw):.6g} (median) gives a "
                f"depth of {np.nanmedian(depth):.4g} m with p_surface {p0:g} Pa; the values "
                "are not absolute pressure in Pa (sensor_msgs/FluidPressure's unit)"
            )
        return t_ns, depth, info
