"""The recording seen as a user sees it: the rerun-sdk's web viewer in headless Chromium."""

from __future__ import annotations

import numpy as np
import pytest

from pipelines.outputs import rerun_screenshot

WHY_NOT = rerun_screenshot.available()


def rgb(png) -> np.ndarray:
    """A screenshot (a path or PNG bytes) as an int array of rows x columns x RGB."""
    import io

    from PIL import Image

    source = io.BytesIO(png) if isinstance(png, bytes) else png
    return np.asarray(Image.open(source).convert("RGB")).astype(int)


@pytest.mark.skipif(WHY_NOT is not None, reason=f"no browser check here: {WHY_NOT}")
def test_the_map_is_drawn_north_up_in_the_web_viewer(tmp_path):
    """A map whose probable points lie north of the origin (y = +5 m) and a GPS track south of it
    (y = -5 m): on the screen the map's red pixels are above the track's green ones, as on the plots."""
    from pipelines.outputs.rerun_recorder import Recorder

    rrd = tmp_path / "north.rrd"
    gps = np.column_stack([np.arange(50.0), np.linspace(-6, 6, 50), np.full(50, -5.0)])
    rec = Recorder(str(rrd), "gslam-test", gps, None)
    x = np.linspace(-6, 6, 400)
    xy = np.column_stack([np.r_[x, x], np.r_[np.full(400, 5.0), np.full(400, 5.3)]])
    rec.map(0, 0.0, xy, np.ones(len(xy)))
    rec.finish({})

    def red_and_green(png) -> tuple[np.ndarray, np.ndarray]:
        pix = rgb(png)
        r, g, b = pix[..., 0], pix[..., 1], pix[..., 2]
        red = np.argwhere((r > 170) & (g < 90) & (b < 90))  # the map's high-probability colour
        green = np.argwhere((g > 150) & (r < 110) & (b < 110))  # the GPS track
        return red, green

    def drawn(png: bytes) -> bool:
        red, green = red_and_green(png)
        return len(red) > 200 and len(green) > 100

    shot = rerun_screenshot.screenshot(rrd, tmp_path / "north.png", ready=drawn)
    red, green = red_and_green(shot)
    assert len(red) > 200 and len(green) > 100, (len(red), len(green))  # the map is drawn where it is
    assert red[:, 0].mean() < green[:, 0].mean() - 50  # rows grow downwards: north is up


@pytest.mark.skipif(WHY_NOT is not None, reason=f"no browser check here: {WHY_NOT}")
def test_mid_timeline_the_path_and_the_plots_show_the_run_so_far(tmp_path):
    """A robot driving east from x = -8 to +8 m in 120 steps of 1 s beside a GPS line, its map growing by 10
    points a step: with the time cursor put at 30 s in the web viewer's time panel, the gold path so far
    runs from the start to the white robot arrow a quarter of the way along, and nothing of it lies beyond;
    the map-points line (its fixed colour, in the plots' column right of the map) runs from the start to
    the cursor, a quarter of the plot's width. At the end both run the whole way. Left to the viewer's own
    time axis (a window of +-30 s around the cursor once the data span a minute) the plots showed a minute
    around the cursor, full width at any time, instead of the run so far."""

    from pipelines.outputs.rerun_recorder import SERIES, Recorder

    rrd = tmp_path / "drive.rrd"
    n = 120
    x = np.linspace(-8.0, 8.0, n)
    rec = Recorder(str(rrd), "gslam-test", np.array([[0.0, -8.0, -3.0], [float(n), 8.0, -3.0]]), None)
    poses = np.column_stack([x, np.zeros(n), np.zeros(n), np.r_[x[0], x[:-1]], np.zeros(n)])
    stats = {"map_points": 10.0 * np.arange(n), "effective_sample_size": np.full(n, 30.0), "step_ms": np.ones(n)}
    rec.rows(np.arange(n), np.arange(n, dtype=float), {}, poses, stats)
    rec.finish({})
    colour = np.array(SERIES["map_points"][1])

    def extents(png) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        full = rgb(png)
        pix = full[70:670, 200:1025]  # the map view
        r, g, b = pix[..., 0], pix[..., 1], pix[..., 2]
        gold = np.argwhere((r > 200) & (g > 170) & (b < 120))[:, 1]
        white = np.argwhere((r > 235) & (g > 235) & (b > 235))[:, 1]
        green = np.argwhere((g > 150) & (r < 110) & (b < 110))[:, 1]
        line = np.argwhere(np.abs(full[:, 1260:] - colour).max(axis=2) < 30)[:, 1]  # the plots, right of the map
        return gold, white, green, line

    def drawn(png: bytes) -> bool:  # (at the end the robot's arrow is hidden: the page is white while it loads)
        gold, _, green, line = extents(png)
        return len(gold) > 50 and len(green) > 100 and len(line) > 30

    shots = [(tmp_path / "end.png", None), (tmp_path / "mid.png", 30.0)]
    end_png, mid_png = rerun_screenshot.screenshots(rrd, shots, ready=drawn)
    gold, white, green, line = extents(mid_png)
    assert len(gold) > 50 and len(white) > 20 and len(green) > 100, (len(gold), len(white), len(green))
    span = green.max() - green.min()  # the GPS line, x = -8 .. 8 m

    def along(cols: np.ndarray) -> float:
        return float((cols - green.min()) / span)

    # At 30 s the robot is at x = -8 + 16 * 30 / 119 = -4.0 m: a quarter of the way.
    assert along(gold.min()) < 0.05 and 0.15 < along(gold.max()) < 0.4, (along(gold.min()), along(gold.max()))
    assert 0.15 < along(np.median(white)) < 0.45 and white.min() >= gold.max() - 10
    gold_end, _, green_end, line_end = extents(end_png)
    assert (gold_end.max() - green_end.min()) / (green_end.max() - green_end.min()) > 0.9
    assert len(line) > 30 and len(line_end) > len(line), (len(line), len(line_end))
    assert np.ptp(line) > 30 and np.ptp(line_end) > 2.5 * np.ptp(line), (np.ptp(line), np.ptp(line_end))
