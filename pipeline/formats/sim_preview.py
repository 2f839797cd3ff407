"""A preview PNG of a simulated mission: polar and Cartesian views of one busy frame of each sonar."""

from __future__ import annotations

import numpy as np

from sonarmap.sim.dataset import SimRun

__all__ = ["render_preview"]


def _pick_preview_frame(run: SimRun, candidates: int = 16) -> int:
    """Frame index with the most labelled object (non-seafloor) pixels in both sonars."""
    idx = np.unique(np.linspace(0, run.n_frames - 1, min(candidates, run.n_frames)).astype(int))
    score = []
    for i in idx:
        f = run.frame(int(i))
        h = f.horizontal.labels
        v = f.vertical.labels
        assert h is not None and v is not None
        score.append(int(((h > 0) & (h < 6)).sum()) + int(((v > 0) & (v < 6)).sum()))
    return int(idx[int(np.argmax(score))])


def render_preview(run: SimRun, index: int | None = None) -> bytes:
    """PNG (bytes): polar and Cartesian views of one horizontal and one vertical ping,
    plus their label images (matplotlib Agg)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    i = _pick_preview_frame(run) if index is None else index
    frame = run.frame(i)
    table = run.world.table
    by_id = {e.id: e.colour for e in table.table}
    # Index = label id: the table's colours (ids without a class stay black).
    colors = [by_id.get(i, "#000000") for i in range(max(by_id) + 1)]
    cmap_l = ListedColormap(colors)
    fig, axes = plt.subplots(2, 3, figsize=(16, 9.5), dpi=90)
    for row, ping in enumerate((frame.horizontal, frame.vertical)):
        r, a = ping.ranges_m, ping.angles_rad
        extent = (np.rad2deg(a[0]), np.rad2deg(a[-1]), r[0], r[-1])
        ax = axes[row, 0]
        ax.imshow(
            ping.image,
            origin="lower",
            aspect="auto",
            cmap="copper",
            extent=extent,
            vmin=0,
            vmax=255,
        )
        ax.set_xlabel("bearing [deg] (+left)" if ping.sonar == "horizontal" else "elevation [deg]")
        if ping.sonar == "horizontal":
            ax.invert_xaxis()
        ax.set_ylabel("range [m]")
        ax.set_title(f"{ping.sonar}: polar image")
        re = np.r_[r - (r[1] - r[0]) / 2, r[-1] + (r[1] - r[0]) / 2]
        ae = np.r_[a[0] - (a[1] - a[0]) / 2, (a[1:] + a[:-1]) / 2, a[-1] + (a[-1] - a[-2]) / 2]
        rr, aa = np.meshgrid(re, ae, indexing="ij")
        if ping.sonar == "horizontal":
            xx, yy = -rr * np.sin(aa), rr * np.cos(aa)
            xl, yl = "right [m]", "forward [m]"
        else:
            xx, yy = rr * np.cos(aa), rr * np.sin(aa)
            xl, yl = "forward [m]", "up [m]"
        ax = axes[row, 1]
        ax.pcolormesh(
            xx, yy, ping.image, cmap="copper", vmin=0, vmax=255, shading="flat", rasterized=True
        )
        ax.set_aspect("equal")
        ax.set_facecolor("black")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(f"{ping.sonar}: Cartesian")
        ax = axes[row, 2]
        ax.pcolormesh(
            xx,
            yy,
            ping.labels,
            cmap=cmap_l,
            vmin=-0.5,
            vmax=len(colors) - 0.5,
            shading="flat",
            rasterized=True,
        )
        ax.set_aspect("equal")
        ax.set_facecolor("black")
        ax.set_xlabel(xl)
        ax.set_title(f"{ping.sonar}: labels")
    shown = [e for e in table.table if e.id != 0]
    handles = [plt.Rectangle((0, 0), 1, 1, color=e.colour) for e in shown]
    fig.legend(handles, [e.name for e in shown], loc="lower center", ncol=6)
    g = frame.gt_pose
    fig.suptitle(
        f"{run.world.scene.name} seed {run.seed} frame {i}: x={g[0]:.1f} m y={g[1]:.1f} m "
        f"yaw={np.rad2deg(g[5]):.0f} deg"
    )
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
