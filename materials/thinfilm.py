"""Thin-film iridescence Fresnel term (Belcour & Barla 2017), RGB, numpy.

Belcour and Barla, "A Practical Extension to Microfacet Theory for the Modeling of Varying
Iridescence", ACM TOG 36(4), 2017. A dielectric film (IOR ``eta2``, thickness ``d``) over a
conductor base (``eta3 + i k3``), seen from air (``eta1 = 1``), replaces the Fresnel term of a
microfacet BRDF.

Per polarisation (s, p), the Airy summation of the multiply reflected waves gives a
reflectance that is a Fourier series in the round-trip phase (paper Sec. 4, Eqs. 9-11)::

    R(lambda) = C0 + 2 sum_{m>=1} Cm cos(m (2 pi OPD / lambda + phi2))
    C0 = R12 + Rs,   Cm = (Rs - T121) r123^m,   Rs = T121^2 R23 / (1 - R12 R23),
    T121 = 1 - R12,  r123 = sqrt(R12 R23),      phi2 = phi21 + phi23,
    OPD = 2 eta2 d cos(theta2)   (optical path difference, nm)

with ``R12, R23`` the interface reflectances, ``phi21 = arg(-r12)`` and ``phi23 = arg(r23)``
the phases of the complex amplitudes (convention ``exp(-i omega t)``, IOR ``eta + i k``).
Integrating against the CIE 1931 colour matching functions is done in closed form
(paper Sec. 5): each CMF is fitted by Gaussians in wavenumber, whose cosine transform is
analytic, :func:`xyz_sensitivity` (fit constants from the paper's supplemental code, as
also published in Khronos ``KHR_materials_iridescence``). The series is truncated after
``orders`` terms (3, as in the paper's code).

RGB: XYZ goes to linear sRGB (IEC 61966-2-1 matrix) and each channel is divided by the
response to a spectrally flat reflectance of 1, so a wavelength-independent reflectance
``R`` maps to ``(R, R, R)`` exactly (the paper gets the same white balance by using the
equal-energy CIE RGB primaries). With an RGB base (``eta3, k3`` per channel), channel ``c``
is taken from the film evaluated over the base ``(eta3[c], k3[c])``. As in the paper's
code, the film IOR fades to 1 for thicknesses below 30 nm (``smoothstep``), so ``d -> 0``
recovers the bare conductor exactly, and the result is clamped to ``[0, 1]``.
"""

from __future__ import annotations

import numpy as np

#: XYZ -> linear sRGB (D65), IEC 61966-2-1.
XYZ_TO_SRGB = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)

# Gaussian fits of the CIE 1931 CMFs in wavenumber (1/m): amplitude, mean, variance; x has a
# second lobe (Belcour & Barla 2017, supplemental code ``evalSensitivity``).
_VAL = np.array([5.4856e-13, 4.4201e-13, 5.2481e-13])
_POS = np.array([1.6810e06, 1.7953e06, 2.2084e06])
_VAR = np.array([4.3278e09, 9.3046e09, 6.6121e09])
_X2 = (9.7470e-14, 2.2399e06, 4.5282e09)
_NORM = 1.0685e-7
#: Thickness (nm) below which the film IOR fades to 1 (paper code: smoothstep(0, 0.03 um)).
FADE_NM = 30.0


def xyz_sensitivity(opd_nm: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Cosine transform of the CMFs: ``int cmf(lambda) cos(2 pi opd / lambda + shift)``.

    Normalised so ``xyz_sensitivity(0, 0)`` is about ``(1, 1, 1)`` (illuminant E, Y = 1).
    ``opd_nm`` and ``shift`` (radians) broadcast; returns ``(..., 3)``.
    """
    phase = 2.0 * np.pi * np.asarray(opd_nm, dtype=np.float64)[..., None] * 1e-9
    shift = np.asarray(shift, dtype=np.float64)[..., None]
    xyz = (
        _VAL
        * np.sqrt(2.0 * np.pi * _VAR)
        * np.cos(_POS * phase + shift)
        * np.exp(-_VAR * phase * phase)
    )
    a, pos, var = _X2
    extra = (
        a
        * np.sqrt(2.0 * np.pi * var)
        * np.cos(pos * phase[..., 0] + shift[..., 0])
        * np.exp(-var * phase[..., 0] ** 2)
    )
    xyz[..., 0] += extra
    return xyz / _NORM


def fresnel_amplitudes(
    cos_i: np.ndarray, n_i: complex | np.ndarray, n_t: complex | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Complex Fresnel amplitude coefficients ``(r_s, r_p)`` from medium ``n_i`` into ``n_t``.

    ``r_s = (n_i c_i - q) / (n_i c_i + q)``, ``r_p = (n_t^2 c_i - n_i q) / (n_t^2 c_i + n_i q)``
    with ``q = n_t cos_t = sqrt(n_t^2 - n_i^2 sin_i^2)`` on the principal branch (``Im q >= 0``:
    a decaying wave for ``n_t = eta + i k``, ``k >= 0``). ``|r|^2`` averaged over s and p is the
    unpolarised reflectance of :func:`materials.microfacet.fresnel_conductor`.
    """
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    n_i = np.asarray(n_i, dtype=np.complex128)
    n_t = np.asarray(n_t, dtype=np.complex128)
    q = np.sqrt(n_t * n_t - n_i * n_i * (1.0 - c * c))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (n_i * c - q) / (n_i * c + q)
        r_p = (n_t * n_t * c - n_i * q) / (n_t * n_t * c + n_i * q)
    # Grazing incidence on a vacuum-like base is 0/0; its limit is total reflection, -1.
    r_s = np.where(np.isfinite(r_s), r_s, -1.0)
    r_p = np.where(np.isfinite(r_p), r_p, -1.0)
    return r_s, r_p


def film_ior(thickness_nm: float, ior: float) -> float:
    """The film IOR used at ``thickness_nm``: faded to 1 below :data:`FADE_NM` (paper code)."""
    t = min(max(thickness_nm / FADE_NM, 0.0), 1.0)
    return 1.0 + (ior - 1.0) * t * t * (3.0 - 2.0 * t)


def airy_reflectance(
    cos_i: np.ndarray,
    thickness_nm: float,
    ior: float,
    eta: float,
    k: float,
    wavelength_nm: np.ndarray,
) -> np.ndarray:
    """Exact unpolarised reflectance of the film stack at single wavelengths (reference).

    Airy's formula ``r = (r12 + r23 e^{i delta}) / (1 + r12 r23 e^{i delta})``,
    ``delta = 2 pi OPD / lambda``, per polarisation, averaged. No IOR fade, no truncation;
    wavelength-independent IORs. ``cos_i`` and ``wavelength_nm`` broadcast.
    """
    c1 = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    c2 = np.sqrt(1.0 - (1.0 - c1 * c1) / (ior * ior))
    delta = 2.0 * np.pi * 2.0 * ior * thickness_nm * c2 / np.asarray(wavelength_nm, np.float64)
    e = np.exp(1j * delta)
    out = 0.0
    for r12, r23 in zip(
        fresnel_amplitudes(c1, 1.0, ior), fresnel_amplitudes(c2, ior, eta + 1j * k), strict=True
    ):
        r = (r12 + r23 * e) / (1.0 + r12 * r23 * e)
        out = out + 0.5 * np.abs(r) ** 2
    return np.asarray(out)


def iridescence_fresnel(
    cos_i: np.ndarray,
    thickness_nm: float,
    ior: float,
    eta: np.ndarray,
    k: np.ndarray,
    *,
    orders: int = 3,
    clamp: bool = True,
) -> np.ndarray:
    """RGB Fresnel reflectance of a thin dielectric film over a conductor (Belcour & Barla).

    Parameters
    ----------
    cos_i
        Cosine of incidence on the film, ``dot(wi, h)`` for a microfacet BRDF; any shape
        ``S`` (a trailing axis of length 1 is dropped from 2-D and higher input).
    thickness_nm
        Film thickness in nanometres, ``>= 0``.
    ior
        Real film IOR, ``>= 1`` (1 means no film).
    eta, k
        ``(3,)`` RGB complex IOR of the base conductor.
    orders
        Number of Fourier orders of the Airy series kept (paper: 3).
    clamp
        Clamp to ``[0, 1]`` as the paper does (the truncated series and CMF fits may
        overshoot by a few thousandths).

    Returns
    -------
    ``S + (3,)`` float64 linear-sRGB reflectance.
    """
    if ior < 1.0:
        raise ValueError(f"film IOR must be >= 1, got {ior}")
    if thickness_nm < 0.0:
        raise ValueError(f"film thickness must be >= 0 nm, got {thickness_nm}")
    c1 = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    if c1.ndim >= 2 and c1.shape[-1] == 1:
        c1 = c1[..., 0]
    eta2 = film_ior(thickness_nm, ior)
    c2 = np.sqrt(1.0 - (1.0 - c1 * c1) / (eta2 * eta2))
    opd = 2.0 * eta2 * thickness_nm * c2
    eta = np.broadcast_to(np.asarray(eta, np.float64), (3,))
    k = np.broadcast_to(np.asarray(k, np.float64), (3,))
    # cos(pos phase + shift) = cos(pos phase) cos(shift) - sin(pos phase) sin(shift): the
    # Gaussian lobes of S(m OPD, .) are computed once per order and shared by the three
    # channels and two polarisations, which differ only in the shift m phi2. Lobes are
    # (x, y, z, second x); ``w`` projects them onto one sRGB channel.
    val = np.append(_VAL, _X2[0]) * np.sqrt(2.0 * np.pi * np.append(_VAR, _X2[2])) / _NORM
    pos, var = np.append(_POS, _X2[1]), np.append(_VAR, _X2[2])
    phase = 2.0 * np.pi * opd[..., None] * 1e-9
    lobes = []
    for m in range(1, orders + 1):
        amp = val * np.exp(-var * (m * phase) ** 2)
        arg = pos * (m * phase)
        lobes.append((amp * np.cos(arg), amp * np.sin(arg)))
    r12 = fresnel_amplitudes(c1, 1.0, eta2)
    out = np.empty(c1.shape + (3,))
    for ch in range(3):
        w = np.append(XYZ_TO_SRGB[ch], XYZ_TO_SRGB[ch, 0])
        white = float(val @ w)  # response to a flat reflectance of 1 (S(0, 0))
        proj = [(lc @ w, ls @ w) for lc, ls in lobes]
        r23 = fresnel_amplitudes(c2, eta2, eta[ch] + 1j * k[ch])
        acc = np.zeros(c1.shape)
        for a12, a23 in zip(r12, r23, strict=True):  # s, then p; depolarise by averaging
            big_r12, big_r23 = np.abs(a12) ** 2, np.abs(a23) ** 2
            t121 = 1.0 - big_r12
            r123 = np.sqrt(big_r12 * big_r23)
            rs = t121 * t121 * big_r23 / np.maximum(1.0 - big_r12 * big_r23, 1e-12)
            phi2 = np.angle(-a12) + np.angle(a23)
            pol = (big_r12 + rs) * white
            cm = rs - t121
            for m, (pc, ps) in enumerate(proj, start=1):
                cm = cm * r123
                pol += 2.0 * cm * (pc * np.cos(m * phi2) - ps * np.sin(m * phi2))
            acc += 0.5 * pol
        out[..., ch] = acc / white
    return np.clip(out, 0.0, 1.0) if clamp else out
