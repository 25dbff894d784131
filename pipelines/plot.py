"""`gslam plot`: the paper's figure for a run: the map's probability, the path, GPS and poles; and the
position error against time."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gslam.metrics import interpolate_positions
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput

from .evaluate import read_result


def plot_result(result: Path, out: Path, reference: Path | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = read_result(result)
    ref_path = reference or Path(res.metadata.get("input", {}).get("path", ""))
    gps = poles = None
    if ref_path and Path(ref_path).exists():
        g, p = [], None
        for msg in McapInput(ref_path).messages([ch.GPS, ch.LANDMARKS_TRUTH]):
            if msg.topic == ch.GPS:
                g.append([msg.t_s, msg.value.pose.position.x, msg.value.pose.position.y])
            else:
                p = np.column_stack([msg.value["x_m"], msg.value["y_m"]])
        gps = np.asarray(g) if g else None
        poles = p
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [1.4, 1]})
    order = np.argsort(res.map_p)
    sc = ax.scatter(
        res.map_xy[order, 0],
        res.map_xy[order, 1],
        c=res.map_p[order] / max(res.map_p.max(), 1e-300),
        s=3,
        cmap="jet",
        label=f"map ({len(res.map_p)} points)",
    )
    fig.colorbar(sc, ax=ax, label="p / max p", shrink=0.8)
    ax.plot(res.trajectory[:, 0], res.trajectory[:, 1], color="gold", lw=1.5, label="G-SLAM path")
    if gps is not None:
        ax.plot(gps[:, 1], gps[:, 2], color="green", lw=0.8, ls="--", label="GPS")
    if poles is not None:
        ax.scatter(poles[:, 0], poles[:, 1], marker="x", c="k", s=40, label="surveyed poles")
    ax.set_aspect("equal")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    cfg = res.metadata["config"]["filter"]
    ax.set_title(f"{res.metadata['input'].get('dataset', '')}: N {cfg['particles']}, M {cfg['points_per_observation']}")
    ax.legend(loc="upper right", fontsize=8)
    if gps is not None:
        t0 = res.t_s[0]
        for traj, name in ((res.trajectory, "final best path"), (res.online, "online estimate")):
            inside, pos = interpolate_positions(res.t_s, traj, gps[:, 0])
            err = np.hypot(*(pos - gps[inside, 1:3]).T)
            ax2.plot(gps[inside, 0] - t0, err, label=f"{name} (mean {err.mean():.2f} m)")
        ax2.set_xlabel("time [s]")
        ax2.set_ylabel("distance to GPS [m]")
        ax2.legend()
        ax2.grid(alpha=0.3)
    else:
        ax2.plot(res.t_s - res.t_s[0], res.step_ms)
        ax2.set_xlabel("time [s]")
        ax2.set_ylabel("step time [ms]")
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, out)
    return out
