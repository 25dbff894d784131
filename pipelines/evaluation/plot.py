"""`gslam plot`: the paper's figure for a run: the map's probability, the path, GPS and poles; and the
position error against time."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mcaplog.mcapio import McapInput
from mcaplog.tempfiles import create_temporary
from mcaplog.tempfiles import replace as replace_temporary
from pipelines.errors import InputError
from pipelines.evaluation.evaluate import ResultData, read_result, reference_truth
from pipelines.evaluation.metrics import interpolate_positions


def _legend_below(ax, ncols: int) -> None:
    """The axes' legend under its x label, outside the data."""
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncols=ncols, fontsize=9, frameon=False, markerscale=2)


def plot_result(result: Path, out: Path, reference: Path | None = None) -> Path:
    """Draw the result's figure and write it to `out` (PNG, atomically)."""
    return save_figure(result_figure(result, reference), out)


def save_figure(fig, out: Path) -> Path:
    """Write a matplotlib figure to `out` (PNG, atomically) and close it."""
    import matplotlib.pyplot as plt

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = create_temporary(out)
    try:
        try:
            with os.fdopen(fd, "wb") as f:
                fig.savefig(f, dpi=110, format="png")
            replace_temporary(tmp, out)
        except OSError as e:  # disk full, I/O error: name the user's path
            raise OSError(e.errno, e.strerror, str(out)) from None
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return out


def step_axis_top(step_ms: np.ndarray) -> float | None:
    """The top of the step-time axis when a few steps are far longer than the rest (1.3 x the 99th
    percentile), else None (the whole range is shown)."""
    step_ms = np.asarray(step_ms, dtype=float)
    if len(step_ms) < 20:
        return None
    top = 1.3 * float(np.percentile(step_ms, 99))
    return top if top > 0 and step_ms.max() > 2 * top else None


def no_steps_line(result: Path, res: ResultData) -> str:
    """Why a result with no steps has nothing to plot: a run interrupted (or failed) before its first scan
    finishes its outputs with no pose, path or step time to draw."""
    r = res.metadata.get("result", {})
    if r.get("interrupted"):
        why = f"the run was interrupted ({r.get('error') or 'interrupted'}) before its first scan"
    else:
        why = "the run processed no scan"
    return f"{result}: no steps to plot: {why}"


def result_figure(result: Path, reference: Path | None = None):
    """The figure of `plot_result` (a matplotlib Figure; the caller closes it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = read_result(result)
    if not len(res.t_s):
        raise InputError(no_steps_line(result, res))
    gps = poles = None
    if reference is not None:
        gps, poles, _ = reference_truth(McapInput(reference))
    # Constrained layout keeps titles, labels, the colour bar and the legends (below the axes, off the
    # data) inside the figure.
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 7.5), gridspec_kw={"width_ratios": [1.4, 1]}, layout="constrained")
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
    if res.metadata.get("initialisation", {}).get("from_gps"):  # the map frame is the GPS's: east, north
        ax.set_xlabel("east [m]")
        ax.set_ylabel("north [m]")
    else:  # a local frame (the odometry's, or the first pose's): no compass directions
        ax.set_xlabel("x [m] (map frame)")
        ax.set_ylabel("y [m]")
    cfg = res.metadata["config"]["filter"]
    ax.set_title(f"{res.metadata['input'].get('dataset', '')}: N {cfg['particles']}, M {cfg['points_per_observation']}")
    _legend_below(ax, ncols=4)
    if gps is not None:
        t0 = res.t_s[0]
        for traj, name in ((res.trajectory, "final best path"), (res.online, "online estimate")):
            inside, pos = interpolate_positions(res.t_s, traj, gps[:, 0])
            err = np.hypot(*(pos - gps[inside, 1:3]).T)
            mean = f"mean {err.mean():.2f} m" if len(err) else "no GPS fix within the run's time span"
            ax2.plot(gps[inside, 0] - t0, err, label=f"{name} ({mean})")
        ax2.set_xlabel("time [s]")
        ax2.set_ylabel("distance to GPS [m]")
        ax2.set_title("position error against GPS")
        _legend_below(ax2, ncols=2)
        ax2.grid(alpha=0.3)
    else:
        ax2.plot(res.t_s - res.t_s[0], res.step_ms, lw=0.8)
        ax2.set_xlabel("time [s]")
        ax2.set_ylabel("step time [ms]")
        ax2.set_title("filter time per step (no GPS to compare with)")
        top = step_axis_top(res.step_ms)
        if top is not None:  # a few long steps would flatten the rest: they are cut and counted
            ax2.set_ylim(0, top)
            n = int((res.step_ms > top).sum())
            ax2.text(
                0.99,
                0.98,
                f"{n} step{'s' if n > 1 else ''} above, longest {res.step_ms.max():.0f} ms",
                transform=ax2.transAxes,
                ha="right",
                va="top",
                fontsize=9,
            )
        ax2.grid(alpha=0.3)
    return fig
