"""Importance-weight normalisation, effective sample size, and Residual Systematic Resampling."""

from __future__ import annotations

from typing import TypeVar

import numpy as np

from gslam.ancestry import AncestryTree

MapT = TypeVar("MapT")


def normalise_log_weights(log_w: np.ndarray) -> np.ndarray:
    """exp(log_w) / sum, computed stably; non-finite entries get zero weight (all non-finite: uniform)."""
    log_w = np.asarray(log_w, dtype=float)
    finite = np.isfinite(log_w)
    if not finite.any():
        return np.full(len(log_w), 1.0 / len(log_w))
    w = np.where(finite, np.exp(log_w - log_w[finite].max()), 0.0)
    return w / w.sum()


def effective_sample_size(weights: np.ndarray) -> float:
    """N_eff = 1 / sum w_i^2 for normalised weights."""
    return float(1.0 / np.sum(np.square(weights)))


def residual_systematic_resampling(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Residual Systematic Resampling (Bolic, Djuric & Hong 2004): indices of the parents.

    For normalised weights w_1..w_N and one uniform draw u ~ U(0, 1/N):
        k_i = floor((w_i - u) N) + 1;   u <- u + k_i / N - w_i
    particle i is replicated k_i times; sum k_i = N. One pass, no sorting, one random number.
    """
    w = np.asarray(weights, dtype=float)
    n = len(w)
    u = rng.uniform(0.0, 1.0 / n)
    counts = np.empty(n, dtype=np.int64)
    for i in range(n):  # over particles (N <= a few hundred), not over points
        k = int(np.floor((w[i] - u) * n)) + 1
        k = max(k, 0)
        counts[i] = k
        u = u + k / n - w[i]
    # Floating-point slack can leave the total one off; fix it on the heaviest particle.
    diff = n - int(counts.sum())
    if diff:
        counts[int(np.argmax(w))] += diff
    return np.repeat(np.arange(n), counts)


def reweight_and_resample(
    weights: np.ndarray, log_likelihood: np.ndarray, threshold: float, rng: np.random.Generator
) -> tuple[np.ndarray, float, np.ndarray | None]:
    """Multiply the importance weights by the step's likelihoods (in logs) and normalise, then draw RSR
    parents when the effective sample size falls below `threshold` x N.

    Returns (normalised weights, effective sample size, parent indices or None when not resampling).
    The caller then continues its particles from the parents (`continue_from_parents`).
    """
    with np.errstate(divide="ignore"):
        w = normalise_log_weights(np.log(weights) + log_likelihood)
    ess = effective_sample_size(w)
    parents = residual_systematic_resampling(w, rng) if ess < threshold * len(w) else None
    return w, ess, parents


def continue_from_parents(
    parents: np.ndarray, poses: np.ndarray, maps: list[MapT], tree: AncestryTree
) -> tuple[np.ndarray, list[MapT], np.ndarray]:
    """The particles after resampling: their parents' poses and maps (maps shared by reference, so
    copy-on-write), histories continued in the ancestry tree, and uniform weights."""
    tree.continue_from(parents)
    return poses[parents], [maps[a] for a in parents], np.full(len(parents), 1.0 / len(parents))
