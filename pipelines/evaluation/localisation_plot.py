"""`gslam plot` on a localisation result: the estimated path over the map it localised in, green where the
filter tracks and red where it is lost, with the reference where there is one; the fitness and the state
against time; and the error against the reference at the tracked scans (else the particle count)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipelines.evaluation.localisation import load_reference, pose_errors, read_localisation
from pipelines.evaluation.plot import save_figure

TRACKING_COLOUR = "#1a9e3f"
LOST_COLOUR = "#d62728"


def plot_localisation(result: Path, out: Path, reference: Path | None = None) -> tuple[Path, list[str]]:
    """Draw the localisation's figure and write it to `out` (PNG, atomically); with the notes on the
    reference (`localisation.load_reference`: none found, none usable)."""
    fig, notes = localisation_figure(result, reference)
    return save_figure(fig, out), notes


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) index pairs, end exclusive, of the runs of True in `mask`."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def localisation_figure(result: Path, reference: Path | None = None):
    """The figure of `plot_localisation` (a matplotlib Figure; the caller closes it) and the notes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    loc = read_localisation(result)
    ref, notes = load_reference(result, loc.metadata, reference)
    has, ref_poses = ref.at(loc) if ref is not None else (np.zeros(len(loc.t_s), dtype=bool), np.empty((0, 3)))
    fig, axes = plt.subplot_mosaic(
        [["map", "fitness"], ["map", "lower"]], figsize=(14, 7.5), width_ratios=[1.4, 1], layout="constrained"
    )
    ax = axes["map"]
    ax.scatter(loc.map_xy[:, 0], loc.map_xy[:, 1], s=3, c="0.2", marker=".", linewidths=0)
    xy = loc.poses[:, :2]
    # Tracked stretches as lines; the estimates while lost as dots (they jump while the filter searches).
    both = loc.tracking[1:] & loc.tracking[:-1]
    segments = np.stack([xy[:-1], xy[1:]], axis=1)[both]
    ax.add_collection(LineCollection(segments, colors=TRACKING_COLOUR, linewidths=1.6, zorder=3))
    lost = ~loc.tracking
    ax.scatter(xy[lost, 0], xy[lost, 1], s=6, color=LOST_COLOUR, linewidths=0, zorder=3)
    handles = [
        Line2D([], [], color="0.2", marker=".", ls="", label=f"map ({len(loc.map_xy)} points)"),
        Line2D([], [], color=TRACKING_COLOUR, lw=2, label=f"estimate, tracking ({int(loc.tracking.sum())} scans)"),
        Line2D([], [], color=LOST_COLOUR, marker=".", ls="", label=f"estimate, lost ({int(lost.sum())} scans)"),
    ]
    if len(ref_poses):
        ax.plot(ref_poses[:, 0], ref_poses[:, 1], color="k", lw=0.7, ls="--", zorder=2)
        handles.append(Line2D([], [], color="k", lw=0.7, ls="--", label="reference"))
    ax.plot(*xy[0], "o", color="k", ms=5, zorder=4)
    handles.append(Line2D([], [], color="k", marker="o", ls="", label="start"))
    first = loc.first_tracking
    t = loc.t_s - loc.t_s[0]
    if first is not None:
        ax.plot(*xy[first], "*", color=TRACKING_COLOUR, mec="k", ms=14, zorder=5)
        handles.append(
            Line2D(
                [],
                [],
                color=TRACKING_COLOUR,
                mec="k",
                marker="*",
                ms=12,
                ls="",
                label=f"first tracking (scan {first}, {t[first]:.0f} s)",
            )  # fmt: skip
        )
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (map frame)")
    ax.set_ylabel("y [m]")
    source = loc.metadata.get("localise", {}).get("map_source", "")
    ax.set_title(
        f"{Path(result).name}: tracking {100 * loc.tracking.mean():.0f} % of {len(t)} scans\n"
        f"map {source.split(',')[0]}",
        fontsize=11,
    )
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncols=3, fontsize=9, frameon=False)

    axf = axes["fitness"]
    band = axf.get_xaxis_transform()
    for mask, colour, name in ((loc.tracking, TRACKING_COLOUR, "tracking"), (~loc.tracking, LOST_COLOUR, "lost")):
        for k, (a, b) in enumerate(_runs(mask)):
            end = t[b] if b < len(t) else t[-1]
            axf.axvspan(t[a], end, color=colour, alpha=0.15, lw=0, label=name if k == 0 else None, transform=band)
    axf.plot(t, loc.fitness, color="tab:blue", lw=0.8, label="fitness")
    axf.set_ylim(0, 1.05)
    axf.set_xlabel("time [s]")
    axf.set_ylabel("fitness (share of the scan explained)")
    axf.set_title("fitness, and the filter's state (shaded)")
    axf.legend(loc="lower right", fontsize=9, ncols=3)
    axf.grid(alpha=0.3)

    axl = axes["lower"]
    scored = has & loc.tracking
    if scored.any():
        trans, _ = pose_errors(loc.poses[scored], ref_poses[loc.tracking[has]])
        axl.plot(t[scored], trans, ".", ms=2, color="tab:purple")
        axl.set_ylabel("position error [m]")
        axl.set_title(f"error at the tracked scans (mean {trans.mean():.3f} m) against\n{ref.what}", fontsize=10)
    else:
        axl.plot(t, loc.particles, color="tab:orange", lw=0.8)
        if loc.particles.min() > 0 and loc.particles.max() > 10 * loc.particles.min():  # thousands while lost
            axl.set_yscale("log")
        axl.set_ylabel("particles")
        axl.set_title("particle count (no reference to compare with)" if ref is None else "particle count")
    axl.set_xlabel("time [s]")
    axl.grid(alpha=0.3)
    return fig, notes
