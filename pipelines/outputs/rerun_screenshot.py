"""A recording as a user sees it: served with the rerun-sdk's own web viewer, opened in headless Chromium,
and photographed (`python -m pipelines.outputs.rerun_screenshot RUN.rrd -o shot.png`).

Needs Chromium (Debian's `chromium`; `GSLAM_CHROMIUM` names another binary) and the `playwright` Python
package (its driver only: the browser is the system's). WebGL runs in Chromium's software rasteriser, so
no GPU or screen is needed. `available()` says what is missing, for tests to skip with that reason.
"""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from pipelines.outputs.rerun_viewer import free_port, rerun_binary, wait_for_port

LOAD_WAIT_S = 30.0
"""Seconds given to the viewer to load its WebAssembly and the recording (about 15 s on 2 cores); with a
`ready` test, the most to wait for it."""

POLL_S = 1.0
"""Seconds between looks at the page while waiting for `ready`."""

TIME_FIELD_XY = (363, 690)
"""The time panel's current-time field in rerun-sdk 0.41's web viewer at 1600 x 900 with our blueprint."""


def chromium() -> str | None:
    return os.environ.get("GSLAM_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


def available() -> str | None:
    """None when a screenshot can be taken here, else why not."""
    if chromium() is None:
        return "no Chromium here (apt-get install chromium, or set GSLAM_CHROMIUM)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install playwright)"
    return None


def screenshot(
    rrd: Path,
    out: Path,
    size: tuple[int, int] = (1600, 900),
    wait_s: float = LOAD_WAIT_S,
    time_s: float | None = None,
    ready: Callable[[bytes], bool] | None = None,
) -> Path:
    """Serve `rrd` with `rerun --web-viewer` on free ports, open it in headless Chromium, wait `wait_s`,
    and write the page as a PNG at `out`. `time_s`: first move the time cursor there on the `time`
    timeline (seconds since the log's start), as a user does, by typing it into the time panel's field
    (`TIME_FIELD_XY`: where the default blueprint puts it at the default size); else the cursor stays
    where the viewer puts it, at the end of the recording. `ready`: given the page as PNG bytes, whether
    the recording is drawn; the wait then ends as soon as it is (looked at every `POLL_S`), or at `wait_s`."""
    return screenshots(rrd, [(out, time_s)], size, wait_s, ready)[0]


def screenshots(
    rrd: Path,
    shots: Sequence[tuple[Path, float | None]],
    size: tuple[int, int] = (1600, 900),
    wait_s: float = LOAD_WAIT_S,
    ready: Callable[[bytes], bool] | None = None,
) -> list[Path]:
    """Several `screenshot`s of one recording, loaded once: `(out, time_s)` in order, each as there; a
    `time_s` of None (the cursor where the viewer put it, at the end) only before any cursor move."""
    from playwright.sync_api import sync_playwright

    why = available()
    if why is not None:
        raise RuntimeError(why)
    times = [t for _, t in shots]
    if any(t is not None for t in times) and size != (1600, 900):
        raise ValueError("time_s needs the default size, where TIME_FIELD_XY is")
    if any(a is not None and b is None for a, b in itertools.pairwise(times)):
        raise ValueError("a shot at the viewer's own cursor (time_s None) must come before any cursor move")
    web, grpc = free_port(), free_port()
    server = subprocess.Popen(
        [rerun_binary(), "--web-viewer", "--web-viewer-port", str(web), "--port", str(grpc), str(rrd)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # `rerun` is a Python wrapper around the viewer binary: end them together
    )
    try:
        wait_for_port("127.0.0.1", web, 30.0)  # the web server is up
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
        args = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium(), args=args)
            try:
                page = browser.new_page(viewport={"width": size[0], "height": size[1]})
                page.goto(url)
                wait_until_drawn(page, wait_s, ready)
                for out, time_s in shots:
                    if time_s is not None:
                        page.mouse.click(*TIME_FIELD_XY)  # (the viewer's UI is one canvas: no DOM to select)
                        time.sleep(1.0)
                        page.keyboard.press("Control+A")
                        page.keyboard.type(f"+{time_s:g}s")
                        page.keyboard.press("Enter")
                        time.sleep(3.0)
                    Path(out).parent.mkdir(parents=True, exist_ok=True)
                    page.screenshot(path=str(out))
            finally:
                browser.close()
    finally:
        stop_group(server)
    return [Path(out) for out, _ in shots]


def wait_until_drawn(page, wait_s: float, ready: Callable[[bytes], bool] | None) -> None:
    """Wait `wait_s`, or with `ready` until the page passes it (then one more look's time, for the
    frame being drawn to settle), whichever comes first."""
    if ready is None:
        time.sleep(wait_s)
        return
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        time.sleep(POLL_S)
        if ready(page.screenshot()):
            time.sleep(POLL_S)
            return


def stop_group(process: subprocess.Popen) -> None:
    """End a process started with `start_new_session=True` and everything it started (SIGTERM, then
    SIGKILL after 10 s)."""
    import signal

    for sig, wait_s in ((signal.SIGTERM, 10), (signal.SIGKILL, 5)):
        try:
            os.killpg(process.pid, sig)
        except ProcessLookupError:
            return
        try:
            process.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


def main() -> int:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rrd", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--wait", type=float, default=LOAD_WAIT_S)
    parser.add_argument("--time", type=float, help="the time cursor at this many seconds (default: the end)")
    a = parser.parse_args()
    why = available()
    if why is not None:
        print(f"error: {why}", file=sys.stderr)
        return 2
    print(f"wrote {screenshot(a.rrd, a.output, wait_s=a.wait, time_s=a.time)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
