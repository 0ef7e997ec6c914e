"""Input checks shared by the calib modules: shapes, finiteness, signs.

Every check raises a :class:`~grassd.calib.errors.InvalidArrayError` subclass whose message
names the argument and says what to fix.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.errors import NegativeValueError, NonFiniteError, ShapeError


def as_float_array(
    value: ArrayLike,
    name: str,
    *,
    last_dim: int | None = None,
    ndim: int | None = None,
    min_size: int = 1,
    non_negative: bool = False,
) -> NDArray[np.float64]:
    """Return ``value`` as a float64 array after checking it.

    Args:
        value: anything numpy can turn into a numeric array.
        name: the argument's name, used in error messages.
        last_dim: required length of the last axis (3 for RGB/XYZ/Lab triplets).
        ndim: required number of dimensions.
        min_size: minimum number of elements (or of triplets when ``last_dim`` is given).
        non_negative: reject negative values (linear light, lengths, standard errors).

    Raises:
        ShapeError, NonFiniteError, NegativeValueError.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(
            f"{name} must be a numeric array; got {type(value).__name__} ({exc})"
        ) from exc
    if ndim is not None and arr.ndim != ndim:
        raise ShapeError(f"{name} must have {ndim} dimension(s); got shape {arr.shape}")
    if last_dim is not None and (arr.ndim == 0 or arr.shape[-1] != last_dim):
        raise ShapeError(
            f"{name} must have a last axis of length {last_dim} (e.g. shape (N, {last_dim})); "
            f"got shape {arr.shape}"
        )
    count = arr.size // last_dim if last_dim else arr.size
    if count < min_size:
        raise ShapeError(f"{name} needs at least {min_size} entries; got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise NonFiniteError(
            f"{name} holds {int(bad.sum())} NaN/Inf value(s) (first at index {first}); "
            "remove or re-measure those samples"
        )
    if non_negative and (arr < 0).any():
        first = tuple(int(i) for i in np.argwhere(arr < 0)[0])
        raise NegativeValueError(
            f"{name} must be non-negative; {int((arr < 0).sum())} value(s) are negative "
            f"(first {arr[first]:.6g} at index {first}); linear light and lengths cannot be < 0"
        )
    return arr


def same_shape(a: NDArray, b: NDArray, name_a: str, name_b: str) -> None:
    """Raise :class:`ShapeError` unless ``a`` and ``b`` have the same shape."""
    if a.shape != b.shape:
        raise ShapeError(
            f"{name_a} and {name_b} must have the same shape; got {a.shape} and {b.shape}"
        )
