"""BTF conventions and direction sets.

**Convention** (UBO2014's, Xu et al. Sec. 3.1 Eq. 1-2): a BTF slice for light ``wi`` and
view ``wo`` is an image over the material's texture plane, ``[row = y, column = x]``, texel
centres at ``(i + 0.5) / res`` of the patch; its value is the reflected radiance divided by
the irradiance *perpendicular to the light*, ``BTF = L_o / E_perp``, so the foreshortening
``cos theta_i`` is included: a flat Lambertian plane gives ``albedo / pi * cos(theta_i)``.
Directions are unit vectors in the patch's frame, z up (the mean plane's normal), x and y
along the texture's columns and rows; angles ``(theta, phi)`` in degrees, ``phi`` from +x
towards +y. Both ``wi`` and ``wo`` point away from the surface.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

#: ``small``: 6 directions (normal, three at 30 degrees, two at 60), all 36 light x view
#: pairs: a few dozen slices spread over the hemisphere.
SMALL_DIRECTIONS: tuple[tuple[float, float], ...] = (
    (0.0, 0.0),
    (30.0, 0.0),
    (30.0, 120.0),
    (30.0, 240.0),
    (60.0, 60.0),
    (60.0, 240.0),
)
#: UBO2014's own dome (btflib's ``create_ubo_dome1_sampling``, Weinmann et al. 2014):
#: ``(theta_deg, azimuth count, azimuth offset_deg)`` per ring, 10 rings from 0 to 75
#: degrees, 151 directions; azimuths evenly spaced from the ring's offset.
UBO_RINGS: tuple[tuple[float, int, float], ...] = (
    (0.0, 1, 0.0),
    (11.0, 6, 15.0),
    (23.5, 12, 0.0),
    (30.0, 12, 15.0),
    (37.5, 12, 0.0),
    (45.0, 18, 0.0),
    (52.5, 18, 7.5),
    (60.0, 24, 0.0),
    (67.5, 24, 7.5),
    (75.0, 24, 0.0),
)
#: The set this project used as ``ubo2014`` before it had UBO2014's dome: 151 directions
#: on 8 rings every 11.25 degrees up to 78.75, alternate rings offset by half a step. Kept
#: as the preset ``rings8_legacy`` because figures in BENCHMARKS.md were measured on it.
LEGACY_RINGS: tuple[tuple[float, int], ...] = tuple((k * 11.25, n) for k, n in enumerate(
    (1, 6, 12, 18, 24, 30, 36, 24)
))  # fmt: skip


def to_vector(theta_deg: ArrayLike, phi_deg: ArrayLike) -> np.ndarray:
    """Unit vectors ``(N, 3)`` of angles in degrees."""
    t = np.radians(np.asarray(theta_deg, dtype=np.float64))
    p = np.radians(np.asarray(phi_deg, dtype=np.float64))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def to_angles(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(theta, phi)`` in degrees of unit vectors ``(N, 3)``; phi in ``[0, 360)``."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.degrees(np.arccos(np.clip(w[..., 2], -1.0, 1.0)))
    phi = np.degrees(np.arctan2(w[..., 1], w[..., 0])) % 360.0
    return theta, phi


def ubo2014_directions() -> np.ndarray:
    """UBO2014's 151 dome directions of :data:`UBO_RINGS`, ``(151, 3)``, ring by ring."""
    dirs = []
    for theta, count, offset in UBO_RINGS:
        for j in range(count):
            dirs.append(to_vector(theta, offset + j * 360.0 / count))
    return np.asarray(dirs)


def legacy_ring_directions() -> np.ndarray:
    """The 151 directions of :data:`LEGACY_RINGS`, ``(151, 3)``."""
    dirs = []
    for k, (theta, count) in enumerate(LEGACY_RINGS):
        offset = 0.5 * (360.0 / count) if k % 2 else 0.0
        for j in range(count):
            dirs.append(to_vector(theta, offset + j * 360.0 / count))
    return np.asarray(dirs)


def preset_pairs(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)``, each ``(N, 3)``: every light x view pair of a preset, light-major."""
    if name == "small":
        dirs = to_vector(*np.asarray(SMALL_DIRECTIONS).T)
    elif name == "ubo2014":
        dirs = ubo2014_directions()
    elif name == "rings8_legacy":
        dirs = legacy_ring_directions()
    else:
        raise ValueError(f"unknown direction preset {name!r}; known: small, ubo2014, rings8_legacy")
    wi = np.repeat(dirs, len(dirs), axis=0)
    wo = np.tile(dirs, (len(dirs), 1))
    return wi, wo


def check_pairs(wi: np.ndarray, wo: np.ndarray, *, max_theta: float = 85.0) -> None:
    """``ValueError`` unless both are ``(N, 3)`` unit vectors above the plane (theta at most
    ``max_theta`` degrees) and no pair repeats."""
    for name, w in (("wi", wi), ("wo", wo)):
        if w.ndim != 2 or w.shape[1] != 3:
            raise ValueError(f"{name} must be (N, 3), got {w.shape}")
        if np.any(np.abs(np.linalg.norm(w, axis=1) - 1.0) > 1e-6):
            raise ValueError(f"{name} must hold unit vectors")
        theta = np.degrees(np.arccos(np.clip(w[:, 2], -1.0, 1.0)))
        if np.any(theta > max_theta + 1e-9):
            raise ValueError(
                f"{name}: directions must lie at most {max_theta} degrees from the normal"
            )
    key = np.round(np.concatenate([wi, wo], axis=1), 9)
    _, counts = np.unique(key, axis=0, return_counts=True)
    if np.any(counts > 1):
        raise ValueError("a light/view pair is listed more than once")


def pair_count_label(n: int) -> str:
    """``"36 slices (6 x 6)"`` style label."""
    side = int(round(math.sqrt(n)))
    return f"{n} slices ({side} x {side})" if side * side == n else f"{n} slices"
