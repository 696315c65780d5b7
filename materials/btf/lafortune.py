"""The 4-lobe Lafortune baseline for BTFs (Xu et al., "Real-Time Neural Materials on Mobile
VR", Sec. 5.3, Eq. 6-7): the model, its parameter layout and a starting point for the fit.

**Model.** Each texel's 4D "apparent BRDF" (the BTF slice values at one texel, see
:mod:`materials.btf.directions` for the convention) is approximated by one diffuse RGB
colour and ``k =`` :data:`LOBES` Lafortune lobes, each with its own RGB specular colour::

    model(wi, wo) = wi.z * ( rho_d + sum_j rho_s_j * max(wo^T M_j wi, 0) ** n_j )

with ``M_j`` a full 3x3 matrix and the exponent clamped to ``n_j >= 1``. ``max(., 0)``
because a negative base to a real power is undefined (the usual Lafortune convention).
The fit itself (Levenberg-Marquardt, per texel) is :mod:`models.btf.lafortune`.

**Deviation from the paper.** Eq. 6 as printed, ``rho_d + sum_j rho_s_j (wo^T M_j wi)^n_j``,
has no ``cos(theta_i)``. A BTF value is ``L_o / E_perp`` and so includes the foreshortening:
a flat Lambertian plane of albedo ``a`` gives ``a / pi * wi.z``, which Eq. 6 cannot
represent (its diffuse term is constant and no lobe is proportional to ``wi.z`` alone). We
multiply the whole model by ``wi.z``; the parameter count is the paper's.

**Layout.** A ``(..., 55)`` float array (:data:`PARAMS_PER_TEXEL`, the paper's 35.2 MB at
400 x 400 texels is 55 float32 per texel)::

    [0:3]                       rho_d, RGB
    per lobe j = 0..3, at o = 3 + 13 j  (:func:`lobe_offset`):
      [o     : o + 9 ]          M_j, row-major (M[a, b] at o + 3 a + b)
      [o + 9         ]          n_j
      [o + 10: o + 13]          rho_s_j, RGB
"""

from __future__ import annotations

import numpy as np

#: Lafortune lobes per texel (the paper's k = 4).
LOBES = 4
#: Floats per lobe: ``M`` (9), ``n`` (1), ``rho_s`` RGB (3).
LOBE_PARAMS = 13
#: Floats per texel: diffuse RGB (3) plus :data:`LOBES` lobes.
PARAMS_PER_TEXEL = 3 + LOBES * LOBE_PARAMS
#: Offsets inside one lobe's block.
M_OFFSET, N_OFFSET, RHO_S_OFFSET = 0, 9, 10
#: The smallest exponent (the model clamps ``n`` to at least this).
MIN_EXPONENT = 1.0
#: The fit's bounds on a lobe (see :mod:`models.btf.lafortune`): exponents at most this,
#: and every ``M`` of spectral norm at most 1, so that ``|wo^T M wi| <= 1`` and no lobe can
#: exceed its colour in directions the fit never saw.
MAX_EXPONENT = 256.0

#: Starting lobes of :func:`initial_params`: ``(diagonal of M, n)``: a sharp and a broad
#: mirror lobe, a retro-reflection lobe and an off-specular / forward-scatter lobe.
INITIAL_LOBES: tuple[tuple[tuple[float, float, float], float], ...] = (
    ((-1.0, -1.0, 1.0), 20.0),
    ((-1.0, -1.0, 1.0), 4.0),
    ((1.0, 1.0, 1.0), 8.0),
    ((0.0, 0.0, 1.0), 2.0),
)
#: :func:`initial_params`: the diffuse colour and each lobe's colour as fractions of the
#: texel's mean ``BTF / wi.z``.
INITIAL_DIFFUSE, INITIAL_SPECULAR = 0.7, 0.05


def lobe_offset(j: int) -> int:
    """Index of lobe ``j``'s first float (its ``M[0, 0]``) in a texel's parameters."""
    if not 0 <= j < LOBES:
        raise ValueError(f"lobe index must be in [0, {LOBES}), got {j}")
    return 3 + LOBE_PARAMS * j


def split_params(params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(rho_d (..., 3), M (..., LOBES, 3, 3), n (..., LOBES), rho_s (..., LOBES, 3))``
    of ``(..., 55)`` parameters (``n`` as stored, not clamped)."""
    p = np.asarray(params)
    if p.shape[-1] != PARAMS_PER_TEXEL:
        raise ValueError(f"params must be (..., {PARAMS_PER_TEXEL}), got {p.shape}")
    lobes = p[..., 3:].reshape(*p.shape[:-1], LOBES, LOBE_PARAMS)
    m = lobes[..., M_OFFSET : M_OFFSET + 9].reshape(*p.shape[:-1], LOBES, 3, 3)
    return p[..., :3], m, lobes[..., N_OFFSET], lobes[..., RHO_S_OFFSET : RHO_S_OFFSET + 3]


def join_params(rho_d: np.ndarray, m: np.ndarray, n: np.ndarray, rho_s: np.ndarray) -> np.ndarray:
    """Inverse of :func:`split_params`: ``(..., 55)`` float64."""
    rho_d = np.asarray(rho_d, dtype=np.float64)
    batch = rho_d.shape[:-1]
    lobes = np.concatenate(
        [
            np.broadcast_to(np.asarray(m, np.float64), (*batch, LOBES, 3, 3)).reshape(
                *batch, LOBES, 9
            ),
            np.broadcast_to(np.asarray(n, np.float64), (*batch, LOBES))[..., None],
            np.broadcast_to(np.asarray(rho_s, np.float64), (*batch, LOBES, 3)),
        ],
        axis=-1,
    )
    return np.concatenate([rho_d, lobes.reshape(*batch, LOBES * LOBE_PARAMS)], axis=-1)


def _check_directions(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    if wi.ndim != 2 or wi.shape[1] != 3 or wo.shape != wi.shape:
        raise ValueError(f"wi and wo must both be (S, 3), got {wi.shape} and {wo.shape}")
    return wi, wo


def lafortune_eval(params: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The model (see the module docstring) of ``T`` texels at ``S`` direction pairs.

    ``params`` is ``(T, 55)``; ``wi`` and ``wo`` are ``(S, 3)`` unit vectors shared by all
    texels. Returns ``(T, S, 3)`` float64.
    """
    p = np.asarray(params, dtype=np.float64)
    if p.ndim != 2:
        raise ValueError(f"params must be (T, {PARAMS_PER_TEXEL}), got {p.shape}")
    wi, wo = _check_directions(wi, wo)
    rho_d, m, n, rho_s = split_params(p)
    base = np.einsum("sa,tjab,sb->tjs", wo, m, wi)  # (T, LOBES, S)
    n = np.maximum(n, MIN_EXPONENT)[..., None]
    positive = base > 0.0
    lobe = np.where(positive, np.power(np.where(positive, base, 1.0), n), 0.0)
    value = rho_d[:, None, :] + np.einsum("tjs,tjc->tsc", lobe, rho_s)
    return wi[None, :, 2, None] * value


def initial_params(mean_rgb: np.ndarray) -> np.ndarray:
    """A starting point ``(..., 55)`` float64 from each texel's mean ``BTF / wi.z`` colour
    ``(..., 3)``: diffuse :data:`INITIAL_DIFFUSE` of it, the lobes of :data:`INITIAL_LOBES`
    each coloured :data:`INITIAL_SPECULAR` of it."""
    mean = np.asarray(mean_rgb, dtype=np.float64)
    if mean.shape[-1:] != (3,):
        raise ValueError(f"mean_rgb must be (..., 3), got {mean.shape}")
    batch = mean.shape[:-1]
    m = np.stack([np.diag(d) for d, _ in INITIAL_LOBES])  # (LOBES, 3, 3)
    n = np.array([e for _, e in INITIAL_LOBES])
    rho_s = np.broadcast_to(INITIAL_SPECULAR * mean[..., None, :], (*batch, LOBES, 3))
    return join_params(INITIAL_DIFFUSE * mean, m, n, rho_s)
