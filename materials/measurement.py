"""Simulated gonioreflectometer imperfections for MERL tables of known ground truth.

Real measured tables (MERL, Matusik et al. 2003) carry multiplicative noise from the camera
and light-source calibration, and lack data at grazing angles, where the sample's projected
area vanishes and the measurement is unreliable. :func:`simulate_measurement` imitates both
so that fitting and scoring code can be exercised against data that looks measured but
whose truth is known.

Model, per bin and channel (channels independent):

- noise: ``value * exp(sigma z - sigma^2 / 2)``, ``z ~ N(0, 1)``: lognormal with mean 1,
  so the expected value is unchanged and the relative spread is about ``sigma``;
- grazing mask: a bin is missing when its canonical direction pair
  (:func:`materials.halfdiff.bin_directions`, ``phi_h = 0``) has ``theta_i`` or
  ``theta_o`` above ``grazing_deg``;
- dropout: each remaining bin is missing with probability ``dropout`` (all three channels).

Missing bins are set to :data:`materials.halfdiff.MISSING`; bins missing in the input stay
missing. Randomness comes only from the ``rng`` argument, so a seeded
``np.random.Generator`` gives identical tables.
"""

from __future__ import annotations

import numpy as np

from materials import halfdiff as hd
from storage.formats.merl import MerlTable


def grazing_mask(phi_d_bins: int = 180, grazing_deg: float = 80.0) -> np.ndarray:
    """``(90, 90, P)`` bool: bins whose canonical pair has ``theta_i`` or ``theta_o`` above
    ``grazing_deg`` (below-horizon pairs included)."""
    wi, wo = hd.bin_directions(phi_d_bins)
    cos_limit = np.cos(np.deg2rad(grazing_deg))
    mask = (wi[:, 2] < cos_limit) | (wo[:, 2] < cos_limit)
    return mask.reshape(hd.RES_THETA_H, hd.RES_THETA_D, phi_d_bins)


def simulate_measurement(
    table: MerlTable,
    rng: np.random.Generator,
    *,
    noise_sigma: float = 0.05,
    grazing_deg: float = 80.0,
    dropout: float = 0.0,
) -> MerlTable:
    """A noisy, incomplete copy of ``table`` (see the module docstring for the model).

    Parameters
    ----------
    table
        The ground truth; not modified.
    rng
        The only source of randomness (e.g. ``np.random.default_rng(seed)``).
    noise_sigma
        Lognormal sigma, ``>= 0`` (0 disables noise).
    grazing_deg
        Polar angle in degrees, ``(0, 90]``, beyond which bins are dropped (90 keeps all
        bins above the horizon).
    dropout
        Probability in ``[0, 1)`` of losing each remaining bin at random.

    Returns
    -------
    A new :class:`MerlTable` with the same ``phi_d_bins``.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    if not np.isfinite(noise_sigma) or noise_sigma < 0:
        raise ValueError(f"noise_sigma must be >= 0, got {noise_sigma!r}")
    if not 0.0 < grazing_deg <= 90.0:
        raise ValueError(f"grazing_deg must be in (0, 90], got {grazing_deg!r}")
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout must be in [0, 1), got {dropout!r}")
    rgb = table.rgb
    # Draw every random number regardless of the mask, so results depend on the seed only.
    z = rng.standard_normal(rgb.shape)
    lost = rng.random(rgb.shape[:3]) < dropout
    noisy = rgb * np.exp(noise_sigma * z - 0.5 * noise_sigma * noise_sigma)
    missing = table.missing | lost | grazing_mask(table.phi_d_bins, grazing_deg)
    out = np.where(missing[..., None], hd.MISSING, noisy)
    return MerlTable(rgb=out, phi_d_bins=table.phi_d_bins)
