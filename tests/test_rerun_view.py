"""The recording seen as a user sees it: the rerun-sdk's web viewer in headless Chromium (issue 24)."""

from __future__ import annotations

import numpy as np
import pytest

from pipelines.outputs import rerun_screenshot

WHY_NOT = rerun_screenshot.available()


@pytest.mark.skipif(WHY_NOT is not None, reason=f"no browser check here: {WHY_NOT}")
def test_the_map_is_drawn_north_up_in_the_web_viewer(tmp_path):
    """A map whose probable points lie north of the origin (y = +5 m) and a GPS track south of it
    (y = -5 m): on the screen the map's red pixels are above the track's green ones, as on the plots."""
    from PIL import Image

    from pipelines.outputs.rerun_process import Recorder

    rrd = tmp_path / "north.rrd"
    gps = np.column_stack([np.arange(50.0), np.linspace(-6, 6, 50), np.full(50, -5.0)])
    rec = Recorder(str(rrd), "gslam-test", gps, None)
    x = np.linspace(-6, 6, 400)
    xy = np.column_stack([np.r_[x, x], np.r_[np.full(400, 5.0), np.full(400, 5.3)]])
    rec.map(0, 0.0, xy, np.ones(len(xy)))
    rec.finish({})
    shot = rerun_screenshot.screenshot(rrd, tmp_path / "north.png")
    pix = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    r, g, b = pix[..., 0], pix[..., 1], pix[..., 2]
    red = np.argwhere((r > 170) & (g < 90) & (b < 90))  # the map's high-probability colour
    green = np.argwhere((g > 150) & (r < 110) & (b < 110))  # the GPS track
    assert len(red) > 200 and len(green) > 100, (len(red), len(green))  # the map is drawn where it is
    assert red[:, 0].mean() < green[:, 0].mean() - 50  # rows grow downwards: north is up
