"""The one check of caller-supplied vectors: right length, every entry finite, or a message naming it."""
from __future__ import annotations

import numpy as np


def finite_vector(v, n: int | None, what: str) -> np.ndarray:
    """``v`` as a float array of shape ``(n,)`` (any length when ``n`` is None).

    Parameters
    ----------
    v : array-like
    n : int or None
        The required length.
    what : str
        What ``v`` is, for the error message.

    Returns
    -------
    ndarray of float

    Raises
    ------
    ValueError
        naming ``what``, when the shape is wrong or an entry is NaN or infinite.
    """
    arr = np.asarray(v, dtype=float)
    if arr.ndim != 1 or (n is not None and arr.shape != (n,)):
        raise ValueError(f"{what} must have {n if n is not None else 'a vector of'} entries, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} has a non-finite entry: {arr.tolist()}")
    return arr
