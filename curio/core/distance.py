"""The exact Euclidean distance transform of a grid (compiled), without SciPy.

:func:`distance_to_features` gives, for every cell, the distance in cells to the nearest
feature cell — what ``scipy.ndimage.distance_transform_edt(~features)`` returns, to the last bit:
both find the exact minimum of the integer squared distance and take its square root in
float64. It is the separable algorithm of Felzenszwalb and Huttenlocher (*Distance transforms
of sampled functions*, Theory of Computing 8, 2012): a nearest-feature scan down each column,
then the lower envelope of parabolas along each row; integer arithmetic throughout (the
breakpoints between parabolas are compared as exact fractions).

The costmap's inflation, the localiser's likelihood field, the tour-stop placement and the
simulator's ray caster use it, and the costmap :func:`dilate_square` (``binary_dilation`` with
a 3 × 3 structure); importing ``scipy.ndimage`` (and ``scipy.special`` with it) for these two
functions cost the rover ~25 MB of memory.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit  # type: ignore[import-untyped]

__all__ = ["dilate_square", "distance_to_features"]

_NONE = np.int64(1) << 40  # "no feature in this column" (larger than any squared distance)


@njit(cache=True, nogil=True)  # type: ignore[misc]
def _squared_edt(features, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``out[r, c]`` = squared distance (cells²) from ``(r, c)`` to the nearest True cell of
    ``features`` (``_NONE`` where there is none at all)."""
    h, w = features.shape
    g = np.empty((h, w), dtype=np.int64)  # squared distance to the nearest feature in the column
    for c in range(w):
        last = -1
        for r in range(h):
            if features[r, c]:
                last = r
            g[r, c] = (r - last) * (r - last) if last >= 0 else _NONE
        last = -1
        for r in range(h - 1, -1, -1):
            if features[r, c]:
                last = r
            if last >= 0:
                d = (last - r) * (last - r)
                if d < g[r, c]:
                    g[r, c] = d
    v = np.empty(w, dtype=np.int64)  # columns of the parabolas in the lower envelope
    for r in range(h):
        k = -1
        for q in range(w):
            fq = g[r, q]
            if fq >= _NONE:
                continue
            # Pop the parabolas that the one at q hides: the intersection of q with v[k] lies
            # at or before that of v[k] with v[k - 1] (compared as fractions, exactly).
            while k >= 1:
                p, pp = v[k], v[k - 1]
                fp, fpp = g[r, p], g[r, pp]
                # s(q, p) <= s(p, pp) ⇔ (fq + q² − fp − p²)(p − pp) <= (fp + p² − fpp − pp²)(q − p)
                if (fq + q * q - fp - p * p) * (p - pp) <= (fp + p * p - fpp - pp * pp) * (q - p):
                    k -= 1
                else:
                    break
            k += 1
            v[k] = q
        if k < 0:
            for q in range(w):
                out[r, q] = _NONE
            continue
        j = 0
        for q in range(w):
            # Move on while the next parabola is lower at q (ties keep the earlier: same value).
            while j < k:
                a, b = v[j], v[j + 1]
                if (q - b) * (q - b) + g[r, b] < (q - a) * (q - a) + g[r, a]:
                    j += 1
                else:
                    break
            a = v[j]
            out[r, q] = (q - a) * (q - a) + g[r, a]


def distance_to_features(features: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """Distance (cells, float64) from every cell to the nearest True cell of the 2-D mask
    ``features``: ``scipy.ndimage.distance_transform_edt(~features)``, bit for bit.

    Raises:
        ValueError: ``features`` is not 2-D, or has no True cell (there is nothing to measure a
            distance to; callers check ``features.any()`` first).
    """
    mask = np.ascontiguousarray(features, dtype=np.bool_)
    if mask.ndim != 2:
        raise ValueError(f"features must be a 2-D mask, got shape {mask.shape}")
    if not mask.any():
        raise ValueError("features has no True cell: there is nothing to measure a distance to")
    sq = np.empty(mask.shape, dtype=np.int64)
    _squared_edt(mask, sq)
    return np.sqrt(sq.astype(np.float64))


def dilate_square(mask: npt.NDArray[np.bool_], iterations: int) -> npt.NDArray[np.bool_]:
    """``mask`` grown ``iterations`` times by its 8 neighbours (cells outside the grid count as
    False): ``scipy.ndimage.binary_dilation(mask, structure=np.ones((3, 3)), iterations=n)``."""
    out = np.array(mask, dtype=np.bool_)
    for _ in range(iterations):
        rows = out.copy()
        rows[1:, :] |= out[:-1, :]
        rows[:-1, :] |= out[1:, :]
        out = rows.copy()
        out[:, 1:] |= rows[:, :-1]
        out[:, :-1] |= rows[:, 1:]
    return out
