"""The Gaussian similarity of eq. 6 (eq. 7 is eq. 6 on features), over batches.

States and features are float64 arrays with one row per point: states (n, d), features phi (n, k).
Distances that overflow (states beyond ~1e150) count as infinite, so their similarity is 0, never NaN.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["gaussian_similarity", "similarity_widths", "squared_distances"]

DIRECT_POINTS = 4  # up to this many query points, distances are taken directly (see squared_distances)


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    ``||a_i - b_j||^2`` for all pairs, by the expansion ``|a|^2 + |b|^2 - 2 a.b`` (one matrix product).

    Both sets are first centred on the mean of ``b``: the expansion cancels catastrophically for points far
    from the origin and close to each other, and centring brings them near it. Rounding can still leave
    small negatives, clipped at 0.

    A few points ``a`` (at most ``DIRECT_POINTS``: one state, as the refit trigger asks) are compared
    directly, sum_d (a_d - b_d)^2, which is cheaper there than a matrix product and exact to rounding.

    :param a: points (n, d)
    :param b: points (m, d)
    :return: (n, m), the transpose of a C-contiguous (m, n) array (C-contiguous for a few points)
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if len(a) <= DIRECT_POINTS:
        with np.errstate(over="ignore", invalid="ignore"):
            differences = b[None, :, :] - a[:, None, :]
            distances = np.einsum("nmd,nmd->nm", differences, differences)
        # As in the expansion below: a point whose squared norm overflows is infinitely far from any other.
        overflowing_a = ~np.isfinite(np.einsum("ij,ij->i", a, a))
        overflowing_b = ~np.isfinite(np.einsum("ij,ij->i", b, b))
        distances[overflowing_a[:, None] | overflowing_b[None, :] | np.isnan(distances)] = np.inf
        return distances
    with np.errstate(over="ignore", invalid="ignore"):
        centre = b.mean(axis=0) if len(b) else np.zeros(b.shape[1])
        a, b = a - centre, b - centre
        a_norms, b_norms = np.einsum("ij,ij->i", a, a), np.einsum("ij,ij->i", b, b)  # (n,), (m,)
        # Built as (m, n), in place: long rows and no (n, m) temporaries, and row sums of the returned
        # transpose (the kernel sums of eq. 8, with m << n samples) add contiguous columns.
        distances = b @ a.T
        distances *= -2.0
        distances += a_norms[None, :]
        distances += b_norms[:, None]
    if max(a_norms.max(initial=0.0), b_norms.max(initial=0.0)) > 1e300:
        # inf - inf only happens between overflowing points: treat them as infinitely far.
        distances[np.isnan(distances)] = np.inf
    return np.maximum(distances, 0.0, out=distances).T


def gaussian_similarity(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
    """
    S_S(a_i, b_j) = exp(-||a_i - b_j||^2 / (2 sigma^2)) (eq. 6).

    :param a: states (n, d)
    :param b: states (m, d)
    :param sigma: width of the Gaussian (> 0)
    :return: (n, m), in [0, 1]
    """
    exponent = squared_distances(a, b)  # (n, m), turned into the similarity in place
    with np.errstate(over="ignore"):  # a huge finite distance over 2 sigma^2 is inf: similarity 0
        exponent *= -1.0 / (2.0 * sigma**2)
    return np.exp(exponent, out=exponent)  # eq. 6


def similarity_widths(sigma: float | Sequence[float] | np.ndarray) -> tuple[float, np.ndarray | None]:
    """
    Eq. 6 with one width per state dimension, as eq. 6 of one width on rescaled states: S with widths
    sigma_d on states s is S with width sigma_1 on the states s_d * sigma_1 / sigma_d.

    :param sigma: one width, or one per dimension (> 0, finite)
    :return: the width sigma_1, and the scale of each dimension (d,) (None when the widths are all equal)
    :raises ValueError: naming ``sigma``
    """
    widths = np.atleast_1d(np.asarray(sigma, dtype=np.float64))
    if widths.ndim != 1 or not len(widths) or not np.all(np.isfinite(widths)) or not np.all(widths > 0):
        raise ValueError(f"sigma must be > 0 and finite (the width of the similarity), got {sigma!r}")
    return float(widths[0]), None if np.all(widths == widths[0]) else widths[0] / widths
