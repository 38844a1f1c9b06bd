"""Small image filters on the host (NumPy), shared by modules that must not depend on
each other."""

from __future__ import annotations

import math

import numpy as np


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of a 2-D image, separable, float64, its edges mirrored with the edge
    pixel repeated (NumPy's ``symmetric`` padding); a kernel of radius ⌈3σ⌉ (at least 1)."""
    r = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    out = np.asarray(image, np.float64)
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        padded = np.pad(out, pad, mode="symmetric")
        out = sum(k[i] * np.take(padded, np.arange(i, i + out.shape[axis]), axis=axis) for i in range(2 * r + 1))
    return out


def box_mean(image: np.ndarray, width: int) -> np.ndarray:
    """Mean over a width×width box (edge-replicated), by cumulative sums."""
    r = max(1, width // 2)
    out = image.astype(np.float64)
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r + 1, r)
        c = np.cumsum(np.pad(out, pad, mode="edge"), axis=axis)
        n = out.shape[axis]
        hi = [slice(None), slice(None)]
        lo = [slice(None), slice(None)]
        hi[axis] = slice(2 * r + 1, 2 * r + 1 + n)
        lo[axis] = slice(0, n)
        out = (c[tuple(hi)] - c[tuple(lo)]) / (2 * r + 1)
    return out.astype(np.float32)
