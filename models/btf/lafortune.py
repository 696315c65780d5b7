"""Levenberg-Marquardt fit of the 4-lobe Lafortune baseline per texel (Xu et al., Sec. 5.3).

The model and its 55-float layout are :mod:`materials.btf.lafortune`'s (note its documented
deviation: the whole model is multiplied by ``wi.z``). Each texel is fitted on its own, to
the sum of squared residuals over its ``S`` direction pairs and three channels, in float64
on the CPU, texels batched in chunks.

**Jacobian (analytic).** A residual is ``r_c(s) = sum_f Phi_f(s) L_fc - y_c(s)`` in terms of
45 per-sample *features* ``Phi`` shared by the channels: ``wi.z``; the four lobe values
``f_j = wi.z max(b_j, 0)^n_j`` with ``b_j = wo^T M_j wi``; and each lobe's geometric
derivatives ``df_j/dM_j[a, b] = wi.z n_j b_j^(n_j - 1) wo_a wi_b`` and
``df_j/dn_j = f_j ln b_j`` (zero where ``b_j <= 0``). Every column of the 3S x 55 Jacobian
is one feature times a channel weight: ``e_c`` for ``rho_d`` and ``rho_s_j`` (features
``wi.z`` and ``f_j``), ``rho_s_j`` for ``M_j`` and ``n_j``. So ``J^T J = Gram[phi, phi] *
(W W^T)`` and ``J^T r = sum_c W B[phi]`` from the 45 x 45 Gram matrix ``Phi^T Phi`` and
``B = Phi^T r`` accumulated over blocks of :data:`PAIR_BLOCK` pairs: memory is bounded by
the chunk and the block, whatever ``S``. ``tests/unit/models/btf`` checks it against
``torch.func.jacfwd``.

**Iteration.** Per texel, the values and colours are first divided by the texel's mean
``|value|`` (the model is linear in the colours, so this only makes the fit independent of
the data's scale; undone at the end). Damping ``lambda`` (start :data:`LAMBDA_START`):
solve ``(J^T J + lambda diag(J^T J) + eps I) delta = -J^T r`` (``eps`` =
:data:`EPS_RELATIVE` times the largest diagonal entry; solved Jacobi-scaled), project the
trial onto the bounds (``1 <= n <= MAX_EXPONENT``, each ``M`` scaled to spectral norm at most
1: unbounded, a lobe fitted to a few dozen directions grows ``wo^T M wi`` past 1 with ``n``
in the hundreds and explodes between them; bounded, a lobe never exceeds its colour),
accept it if its sum of squared residuals is lower (``lambda /=
3``), else keep the old point (``lambda *= 2``); a trial with a non-finite value is
rejected. A fixed number of iterations, no randomness: the same inputs give the same bytes,
whatever ``chunk``. Across thread counts torch's reductions may round differently: run
inside :func:`models.brdf.train.deterministic_torch` (one thread) for bytes that depend on
the inputs only; one thread is also the faster on a small, shared CPU (1024 texels x 300
pairs x 40 iterations: about 9 s).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from materials.btf.lafortune import (
    LOBE_PARAMS,
    LOBES,
    MAX_EXPONENT,
    MIN_EXPONENT,
    N_OFFSET,
    PARAMS_PER_TEXEL,
    RHO_S_OFFSET,
    initial_params,
    lafortune_eval,
)

#: Direction pairs per accumulation block (bounds the features' memory: chunk x block x 45).
PAIR_BLOCK = 128
#: Features per sample: ``wi.z``, the lobes' values, their ``M`` (9) and ``n`` derivatives.
FEATURES = 1 + LOBES + 10 * LOBES
#: Damping: start, factor on an accepted / rejected step, bounds.
LAMBDA_START, LAMBDA_DOWN, LAMBDA_UP = 0.1, 3.0, 2.0
LAMBDA_MIN, LAMBDA_MAX = 1e-15, 1e15
#: ``eps`` of the damped system, relative to the largest diagonal entry of ``J^T J``.
EPS_RELATIVE = 1e-12

DTYPE = torch.float64


@dataclass(frozen=True)
class FitResult:
    """``params`` ``(T, 55)`` float32; ``l1`` ``(T,)`` float64: each texel's mean absolute
    error over its pairs and channels (of the float32 parameters); ``iterations`` run."""

    params: np.ndarray
    l1: np.ndarray
    iterations: int


def _feature_index() -> torch.Tensor:
    """The feature (column of ``Phi``) of each of the 55 parameters."""
    index = [0, 0, 0]
    for j in range(LOBES):
        index += [1 + LOBES + 10 * j + k for k in range(10)]  # M (9), n
        index += [1 + j] * 3  # rho_s RGB
    return torch.tensor(index, dtype=torch.long)


_PHI = _feature_index()
#: The colour parameters (``rho_d`` and every ``rho_s``): the model is linear in them.
_COLOURS = [0, 1, 2] + [
    3 + LOBE_PARAMS * j + RHO_S_OFFSET + c for j in range(LOBES) for c in range(3)
]


def _channel_weights(params: torch.Tensor) -> torch.Tensor:
    """``W`` ``(T, 55, 3)``: the channel weight of each parameter's Jacobian column."""
    t = params.shape[0]
    eye = torch.eye(3, dtype=params.dtype)
    w = torch.zeros((t, PARAMS_PER_TEXEL, 3), dtype=params.dtype)
    w[:, 0:3] = eye
    for j in range(LOBES):
        o = 3 + LOBE_PARAMS * j
        rho_s = params[:, o + RHO_S_OFFSET : o + RHO_S_OFFSET + 3]
        w[:, o : o + 10] = rho_s[:, None, :]
        w[:, o + RHO_S_OFFSET : o + RHO_S_OFFSET + 3] = eye
    return w


def _unpack(params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(L (T, 1 + LOBES, 3): rho_d and rho_s, M (T, LOBES, 9), n (T, LOBES) clamped)``."""
    lobes = params[:, 3:].reshape(-1, LOBES, LOBE_PARAMS)
    colours = torch.cat([params[:, None, 0:3], lobes[..., RHO_S_OFFSET : RHO_S_OFFSET + 3]], 1)
    return colours, lobes[..., 0:9], lobes[..., N_OFFSET].clamp(min=MIN_EXPONENT)


def _pair_products(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """``(9, S)``: ``wo_a wi_b`` at row ``3 a + b`` (what ``M[a, b]`` multiplies)."""
    return (wo[:, :, None] * wi[:, None, :]).reshape(-1, 9).T.contiguous()


def _features(
    m: torch.Tensor, n: torch.Tensor, wz: torch.Tensor, pairs: torch.Tensor
) -> torch.Tensor:
    """``Phi`` ``(T, FEATURES, s)`` at one block of pairs (see the module docstring):
    ``wz`` ``(s,)`` is ``wi.z``, ``pairs`` ``(9, s)`` is :func:`_pair_products`."""
    t, s = m.shape[0], wz.shape[0]
    phi = torch.empty((t, FEATURES, s), dtype=m.dtype)
    base = torch.matmul(m, pairs)  # (T, LOBES, s)
    positive = (base > 0.0).to(m.dtype)
    clipped = base.clamp(min=0.0)
    ex = n[..., None]
    value = phi[:, 1 : 1 + LOBES]
    torch.mul(clipped**ex, wz, out=value)  # 0 ** n = 0 as n >= 1
    slope = (wz * positive) * ex * clipped ** (ex - 1.0)
    grads = phi[:, 1 + LOBES :].view(t, LOBES, 10, s)
    torch.mul(slope[:, :, None, :], pairs, out=grads[:, :, :9])
    # d/dn = value ln(base); value is zero where base <= 0, and the clamp keeps ln finite
    torch.mul(value, torch.log(base.clamp(min=1e-300)), out=grads[:, :, 9])
    phi[:, 0] = wz
    return phi


def normal_equations(
    params: torch.Tensor, values: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(J^T J (T, 55, 55), J^T r (T, 55), sum r^2 (T,))`` of the residuals ``model -
    values`` (``values`` ``(T, S, 3)``, the residuals ordered by pair, then channel) at
    ``params`` ``(T, 55)``; the Jacobian is with respect to the stored parameters, with ``n``
    clamped to at least 1 (so ``params`` should hold clamped exponents)."""
    return _normal_equations(params, values.transpose(1, 2), wi[:, 2], _pair_products(wi, wo))


def _normal_equations(
    params: torch.Tensor, values_t: torch.Tensor, wz: torch.Tensor, pairs: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`normal_equations` of ``values_t`` ``(T, 3, S)``, ``wz`` ``(S,)`` and
    :func:`_pair_products`."""
    colours, m, n = _unpack(params)
    colours_t = colours.transpose(1, 2).contiguous()  # (T, 3, 1 + LOBES)
    t = params.shape[0]
    gram = torch.zeros((t, FEATURES, FEATURES), dtype=params.dtype)
    phi_r = torch.zeros((t, FEATURES, 3), dtype=params.dtype)
    sse = torch.zeros(t, dtype=params.dtype)
    for start in range(0, wz.shape[0], PAIR_BLOCK):
        stop = start + PAIR_BLOCK
        phi = _features(m, n, wz[start:stop], pairs[:, start:stop])
        r = torch.bmm(colours_t, phi[:, : 1 + LOBES]) - values_t[:, :, start:stop]  # (T, 3, s)
        sse += (r * r).sum(dim=(1, 2))
        gram += torch.bmm(phi, phi.transpose(1, 2))
        phi_r += torch.bmm(phi, r.transpose(1, 2))
    w = _channel_weights(params)
    jtj = gram[:, _PHI][:, :, _PHI] * torch.bmm(w, w.transpose(1, 2))
    jtr = (w * phi_r[:, _PHI]).sum(dim=-1)
    return jtj, jtr, sse


def _clamp_exponents(params: torch.Tensor) -> torch.Tensor:
    """Project onto the fit's bounds: ``1 <= n <= MAX_EXPONENT`` and each ``M`` scaled down
    to spectral norm at most 1 (see the module docstring)."""
    out = params.clone()
    idx = [3 + LOBE_PARAMS * j + N_OFFSET for j in range(LOBES)]
    out[:, idx] = out[:, idx].clamp(min=MIN_EXPONENT, max=MAX_EXPONENT)
    for j in range(LOBES):
        o = 3 + LOBE_PARAMS * j
        m = out[:, o : o + 9].reshape(-1, 3, 3)
        norm = torch.linalg.matrix_norm(m, ord=2)
        out[:, o : o + 9] = (m / torch.clamp(norm, min=1.0)[:, None, None]).reshape(-1, 9)
    return out


def _damped_step(jtj: torch.Tensor, jtr: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """``delta`` of ``(J^T J + lambda D + eps max(D) I) delta = -J^T r``, ``D = diag(J^T J)``,
    solved in Jacobi-scaled variables (scaled by ``max(D, eps max(D))``, which changes the
    rounding, not the system). A parameter without influence (``D = 0``, so its whole row is
    zero, e.g. ``M`` of a colourless lobe) gets ``delta = 0``."""
    diag = torch.diagonal(jtj, dim1=1, dim2=2)
    tiny = EPS_RELATIVE * diag.amax(dim=1, keepdim=True)
    scale = torch.maximum(diag, tiny).rsqrt()
    a = jtj * scale[:, :, None] * scale[:, None, :]
    damping = (lam[:, None] * diag + tiny) * scale * scale
    z = torch.linalg.solve(a + torch.diag_embed(damping), -jtr * scale)
    return z * scale


def _fit_chunk(
    start_params: np.ndarray,
    values: np.ndarray,
    wi: torch.Tensor,
    wo: torch.Tensor,
    iterations: int,
    step_done: Callable[[int], None],
) -> np.ndarray:
    # the model is linear in the colours: fit values / (mean |value|) for scale invariance
    level = np.abs(values).mean(axis=(1, 2), dtype=np.float64)
    level = torch.from_numpy(np.where(level > 0.0, level, 1.0))[:, None]
    p = _clamp_exponents(torch.from_numpy(np.array(start_params, np.float64)))
    p[:, _COLOURS] /= level
    y = torch.from_numpy(np.array(np.swapaxes(values, 1, 2), dtype=np.float64)) / level[..., None]
    wz, pairs = wi[:, 2].contiguous(), _pair_products(wi, wo)
    t = p.shape[0]
    jtj, jtr, sse = _normal_equations(p, y, wz, pairs)
    lam = torch.full((t,), LAMBDA_START, dtype=DTYPE)
    for it in range(iterations):
        delta = _damped_step(jtj, jtr, lam)
        trial = _clamp_exponents(p + delta)
        jtj_t, jtr_t, sse_t = _normal_equations(trial, y, wz, pairs)
        finite = (
            torch.isfinite(trial).all(dim=1)
            & torch.isfinite(jtj_t).all(dim=(1, 2))
            & torch.isfinite(jtr_t).all(dim=1)
        )
        ok = finite & (sse_t < sse)
        p = torch.where(ok[:, None], trial, p)
        jtj = torch.where(ok[:, None, None], jtj_t, jtj)
        jtr = torch.where(ok[:, None], jtr_t, jtr)
        sse = torch.where(ok, sse_t, sse)
        lam = torch.where(ok, lam / LAMBDA_DOWN, lam * LAMBDA_UP).clamp(LAMBDA_MIN, LAMBDA_MAX)
        step_done(it + 1)
    p[:, _COLOURS] *= level
    return p.numpy()


def fit_lafortune(
    values: np.ndarray,
    wi: np.ndarray,
    wo: np.ndarray,
    *,
    iterations: int = 40,
    chunk: int = 4096,
    init: np.ndarray | None = None,
    progress: Callable[[float], None] | None = None,
) -> FitResult:
    """Fit each texel's observed BTF values ``(T, S, 3)`` at the pairs ``wi``, ``wo`` (each
    ``(S, 3)``) by Levenberg-Marquardt (see the module docstring), ``chunk`` texels at a
    time. ``init`` ``(T, 55)`` defaults to :func:`~materials.btf.lafortune.initial_params`
    of each texel's mean ``values / wi.z``. ``progress(fraction)`` after every iteration."""
    y = np.asarray(values)
    wi64 = np.asarray(wi, dtype=np.float64)
    wo64 = np.asarray(wo, dtype=np.float64)
    if wi64.ndim != 2 or wi64.shape[1] != 3 or wo64.shape != wi64.shape:
        raise ValueError(f"wi and wo must both be (S, 3), got {wi64.shape} and {wo64.shape}")
    if y.ndim != 3 or y.shape[1:] != (wi64.shape[0], 3):
        raise ValueError(f"values must be (T, {wi64.shape[0]}, 3), got {y.shape}")
    if not np.isfinite(y).all():
        raise ValueError("values must be finite")
    if np.any(wi64[:, 2] <= 0.0) or np.any(wo64[:, 2] <= 0.0):
        raise ValueError("wi and wo must lie above the plane (z > 0)")
    if iterations < 0 or chunk < 1:
        raise ValueError(f"need iterations >= 0 and chunk >= 1, got {iterations}, {chunk}")
    t = y.shape[0]
    if init is not None and np.shape(init) != (t, PARAMS_PER_TEXEL):
        raise ValueError(f"init must be ({t}, {PARAMS_PER_TEXEL}), got {np.shape(init)}")
    wi_t, wo_t = torch.from_numpy(wi64), torch.from_numpy(wo64)
    params = np.empty((t, PARAMS_PER_TEXEL), dtype=np.float32)
    l1 = np.empty(t, dtype=np.float64)
    for lo in range(0, t, chunk):
        hi = min(lo + chunk, t)

        def step_done(it: int, lo: int = lo, hi: int = hi) -> None:
            if progress is not None:
                progress((lo + (hi - lo) * it / max(iterations, 1)) / max(t, 1))

        if init is None:
            start = initial_params((y[lo:hi] / wi64[None, :, 2, None]).mean(axis=1))
        else:
            start = np.asarray(init[lo:hi], dtype=np.float64)
        fitted = _fit_chunk(start, y[lo:hi], wi_t, wo_t, iterations, step_done)
        params[lo:hi] = fitted.astype(np.float32)
        error = lafortune_eval(params[lo:hi], wi64, wo64) - y[lo:hi]
        l1[lo:hi] = np.abs(error).mean(axis=(1, 2))
    if progress is not None:
        progress(1.0)
    return FitResult(params=params, l1=l1, iterations=iterations)
