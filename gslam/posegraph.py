"""The pose graph: nodes (poses), relative-pose constraints between them, optimised by gtsam.

An edge says that node j, seen from node i, stands at `measured` (x, y, heading in i's frame), with
independent Gaussian errors of `sigmas`. Sequential edges come from the front end (the filter's
trajectory between consecutive nodes); loop-closure edges from matching a node's scan against a submap
far back in time (`gslam.loopclosure`), under a robust loss (Huber): a closure that disagrees with the
rest pulls with a bounded force, so one wrong closure is outvoted. After the optimisation, a closure whose
residual still exceeds `reject_chi2` is dropped and the graph optimised again (`optimise_robust`).

The solver is gtsam's Levenberg-Marquardt on Pose2 factors (sparse Cholesky, C++). It was chosen over
scipy's `least_squares` with a sparse Jacobian by measurement (docs/CHOICES.md, "Back end").
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from gslam.se2 import compose, inverse

SEQUENTIAL, CLOSURE, PREVIOUS = 0, 1, 2
"""PREVIOUS: a closure of an earlier mapping run, kept at its optimised relative pose (no robust loss)."""


@dataclass
class Edge:
    i: int
    j: int
    measured: np.ndarray  # (3,) node j in node i's frame
    sigmas: np.ndarray  # (3,) m, m, rad
    kind: int = SEQUENTIAL
    score: float = 0.0  # a closure's match score


@dataclass
class Optimised:
    """The optimised poses, and which closures were kept."""

    poses: np.ndarray
    kept: list[int]  # indices into the edges of the closures kept
    rejected: list[int]
    seconds: float
    iterations: int
    chi2: np.ndarray = field(default_factory=lambda: np.empty(0))  # per edge, whitened squared residual


def residuals(poses: np.ndarray, edges: list[Edge]) -> np.ndarray:
    """Whitened squared residual of every edge at `poses` (sum over x, y, heading of (error / sigma)^2)."""
    if not edges:
        return np.empty(0)
    i = np.array([e.i for e in edges])
    j = np.array([e.j for e in edges])
    z = np.array([e.measured for e in edges])
    sig = np.array([e.sigmas for e in edges])
    est = compose(inverse(poses[i]), poses[j])
    err = compose(inverse(z), est)
    return np.sum((err / sig) ** 2, axis=1)


def optimise(
    poses: np.ndarray, edges: list[Edge], huber_k: float = 1.0, max_iterations: int = 50
) -> tuple[np.ndarray, int]:
    """Levenberg-Marquardt from `poses` (N, 3) over `edges`, node 0 held fixed; closures under a Huber loss
    of scale `huber_k` (whitened units). Returns (poses, iterations)."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, p in enumerate(poses):
        values.insert(k, gtsam.Pose2(float(p[0]), float(p[1]), float(p[2])))
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*map(float, poses[0])), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    robust = gtsam.noiseModel.mEstimator.Huber.Create(huber_k)
    for e in edges:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(e.sigmas, dtype=float))
        if e.kind == CLOSURE:
            noise = gtsam.noiseModel.Robust.Create(robust, noise)
        graph.add(gtsam.BetweenFactorPose2(e.i, e.j, gtsam.Pose2(*map(float, e.measured)), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    out = np.array(
        [[result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()] for k in range(len(poses))]
    )
    return out, int(opt.iterations())


def optimise_robust(
    poses: np.ndarray, edges: list[Edge], huber_k: float = 1.0, reject_chi2: float = 16.0, rounds: int = 3
) -> Optimised:
    """`optimise`, then drop the closures whose whitened squared residual exceeds `reject_chi2` and optimise
    again (from the initial poses), until none is dropped or after `rounds` rounds."""
    t0 = time.perf_counter()
    active = list(range(len(edges)))
    rejected: list[int] = []
    iterations = 0
    out = poses
    chi2 = np.empty(0)
    for _ in range(rounds):
        use = [edges[k] for k in active]
        out, its = optimise(poses, use, huber_k)
        iterations += its
        chi2 = residuals(out, edges)
        bad = [k for k in active if edges[k].kind == CLOSURE and chi2[k] > reject_chi2]
        if not bad:
            break
        rejected += bad
        dropped = set(bad)
        active = [k for k in active if k not in dropped]
    else:
        out, its = optimise(poses, [edges[k] for k in active], huber_k)
        iterations += its
        chi2 = residuals(out, edges)
    kept = [k for k in active if edges[k].kind == CLOSURE]
    return Optimised(out, kept, rejected, time.perf_counter() - t0, iterations, chi2)
