"""Periodic (tileable) noise over a square grid: the building blocks of procedural surfaces.

Arrays are ``(n, n)`` indexed ``[row = y, column = x]``, cell centres at ``i + 0.5``; every
function is seeded only through the ``numpy.random.Generator`` it is given, and tiles
without seams (it is periodic with period ``n`` in both directions).
"""

from __future__ import annotations

import math

import numpy as np


def gaussian_noise(rng: np.random.Generator, n: int, sx: float, sy: float) -> np.ndarray:
    """White noise low-passed by a periodic Gaussian of correlation lengths ``sx``, ``sy``
    cells (x = columns, y = rows); zero mean, unit RMS."""
    white = rng.standard_normal((n, n))
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.fftfreq(n)[None, :]
    kernel = np.exp(-2.0 * math.pi**2 * ((fx * sx) ** 2 + (fy * sy) ** 2))
    h = np.real(np.fft.ifft2(np.fft.fft2(white) * kernel))
    h -= h.mean()
    return h / max(float(h.std()), 1e-12)


def fbm(rng: np.random.Generator, n: int, octaves: int = 5, gain: float = 0.5) -> np.ndarray:
    """Fractal sum of :func:`gaussian_noise` octaves (correlation halving, amplitude times
    ``gain`` per octave); zero mean, unit RMS."""
    h = np.zeros((n, n))
    amp, length = 1.0, n / 4.0
    for _ in range(octaves):
        h += amp * gaussian_noise(rng, n, length, length)
        amp *= gain
        length = max(length / 2.0, 0.5)
    h -= h.mean()
    return h / max(float(h.std()), 1e-12)


def periodic_distance(a: np.ndarray, b: float, n: float) -> np.ndarray:
    """``|a - b|`` on a circle of circumference ``n``."""
    d = np.abs(a - b) % n
    return np.minimum(d, n - d)


def worley(rng: np.random.Generator, n: int, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Periodic Worley noise of ``cells`` random feature points: ``(f1, f2 - f1)`` (distance
    to the nearest point, and the margin to the second nearest, which is 0 on the cells'
    borders), in cells of the grid, and the index of the nearest point as a float array."""
    pts = rng.uniform(0.0, n, size=(cells, 2))
    y, x = np.mgrid[0:n, 0:n].astype(np.float64) + 0.5
    d = np.stack(
        [np.hypot(periodic_distance(x, px, n), periodic_distance(y, py, n)) for px, py in pts]
    )
    order = np.argsort(d, axis=0)
    srt = np.take_along_axis(d, order[:2], axis=0)
    return srt[1] - srt[0], order[0].astype(np.float64)
