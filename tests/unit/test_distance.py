"""The compiled Euclidean distance transform equals SciPy's, to the last bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from curio.core.distance import distance_to_features


def _scipy(features: np.ndarray) -> np.ndarray:
    return np.asarray(ndimage.distance_transform_edt(~features), dtype=np.float64)


@pytest.mark.parametrize("shape", [(1, 1), (1, 17), (23, 1), (40, 60), (97, 31)])
@pytest.mark.parametrize("density", [0.0005, 0.02, 0.3, 0.9])
def test_random_masks(shape: tuple[int, int], density: float) -> None:
    rng = np.random.default_rng(shape[0] * 1000 + shape[1] + int(density * 1e4))
    for _ in range(5):
        mask = rng.random(shape) < density
        if not mask.any():
            mask[rng.integers(shape[0]), rng.integers(shape[1])] = True
        assert np.array_equal(distance_to_features(mask), _scipy(mask))


def test_structured_masks() -> None:
    """Walls, a single point in a corner, stripes, everything: the ties of a real map."""
    m = np.zeros((120, 200), dtype=bool)
    m[0, :] = m[-1, :] = m[:, 0] = m[:, -1] = True
    m[40:80, 100] = True
    m[60, 30:70] = True
    cases = [m, np.eye(50, 70, dtype=bool), np.zeros((30, 30), dtype=bool)]
    cases[2][29, 0] = True
    stripes = np.zeros((64, 64), dtype=bool)
    stripes[::7, :] = True
    cases += [stripes, stripes.T.copy(), np.ones((5, 9), dtype=bool)]
    for mask in cases:
        assert np.array_equal(distance_to_features(mask), _scipy(mask))


def test_an_empty_mask_is_refused() -> None:
    with pytest.raises(ValueError, match="no True cell"):
        distance_to_features(np.zeros((3, 4), dtype=bool))


@pytest.mark.parametrize("iterations", [1, 2, 3])
def test_dilate_square_is_scipys_binary_dilation(iterations: int) -> None:
    from curio.core.distance import dilate_square

    rng = np.random.default_rng(iterations)
    for shape in ((1, 1), (5, 1), (40, 33)):
        for density in (0.01, 0.2):
            mask = rng.random(shape) < density
            ref = ndimage.binary_dilation(mask, structure=np.ones((3, 3), dtype=bool),
                                          iterations=iterations)
            assert np.array_equal(dilate_square(mask, iterations), ref)
