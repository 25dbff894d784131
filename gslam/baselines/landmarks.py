"""Point landmarks from a laser scan, for the landmark baselines (FastSLAM): pole centres as (range, bearing).

Two extractors:
- `poles_from_intensity`: beams with a reflective return (intensity > 0; the Car Park's SICK marks pole
  tape with codes 8192..32768) grouped into runs of adjacent beams with continuous range; one pole per
  run, at the run's mean bearing and its nearest range plus the pole radius (the laser sees the near
  side of the pole).
- `poles_from_geometry`, for logs without intensity: narrow foreground segments. Runs of adjacent returns
  with continuous range, at most `max_width_m` wide, standing at least `min_jump_m` in front of the
  beams on both sides; one pole per segment, as above.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gslam.scan import Scan


@dataclass(frozen=True)
class PoleExtractorConfig:
    pole_radius_m: float = 0.10
    """Added to the nearest range of a run: the centre lies one radius behind the near side."""
    max_range_jump_m: float = 0.3
    """Adjacent beams whose ranges differ by more than this belong to different runs."""
    max_width_m: float = 0.6
    """Geometric extractor: widest segment taken for a pole."""
    min_jump_m: float = 0.5
    """Geometric extractor: how far in front of both neighbouring beams a segment must stand."""
    max_range_m: float = 40.0
    """Returns farther than this are ignored (the reflectivity and the angular width become unreliable)."""


def _runs(idx: np.ndarray, ranges: np.ndarray, jump: float) -> list[np.ndarray]:
    """Split sorted beam indices into runs of adjacent beams with continuous range."""
    if len(idx) == 0:
        return []
    breaks = (np.diff(idx) > 1) | (np.abs(np.diff(ranges[idx])) > jump)
    return np.split(idx, np.flatnonzero(breaks) + 1)


def _centres(scan: Scan, runs: list[np.ndarray], cfg: PoleExtractorConfig) -> tuple[np.ndarray, np.ndarray]:
    bearings = scan.geometry.bearings_rad
    r = np.array([scan.ranges_m[run].min() + cfg.pole_radius_m for run in runs])
    b = np.array([bearings[run].mean() for run in runs])
    return r.reshape(-1), b.reshape(-1)


def poles_from_intensity(
    scan: Scan, intensities: np.ndarray, cfg: PoleExtractorConfig | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(range_m, bearing_rad) of the pole centres marked by reflective returns."""
    cfg = cfg or PoleExtractorConfig()
    ok = scan.returns & (np.asarray(intensities) > 0) & (scan.ranges_m <= cfg.max_range_m)
    return _centres(scan, _runs(np.flatnonzero(ok), scan.ranges_m, cfg.max_range_jump_m), cfg)


def poles_from_geometry(scan: Scan, cfg: PoleExtractorConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(range_m, bearing_rad) of narrow foreground segments (logs without intensity)."""
    cfg = cfg or PoleExtractorConfig()
    r = scan.occlusion_ranges_m
    ok = scan.returns & (scan.ranges_m <= cfg.max_range_m)
    keep = []
    for run in _runs(np.flatnonzero(ok), scan.ranges_m, cfg.max_range_jump_m):
        near = r[run].min()
        width = near * scan.geometry.angle_increment_rad * len(run)
        left, right = run[0] - 1, run[-1] + 1
        if left < 0 or right >= len(r) or width > cfg.max_width_m:
            continue
        if r[left] - near >= cfg.min_jump_m and r[right] - near >= cfg.min_jump_m:
            keep.append(run)
    return _centres(scan, keep, cfg)
