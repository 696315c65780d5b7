"""Levenberg-Marquardt fit of the 4-lobe Lafortune baseline (Xu et al. Sec. 5.3): each test
names its reference: data made by the model itself with known parameters, the Lambertian
plane of the UBO2014 convention, ``torch.func.jacfwd`` for the analytic Jacobian."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import torch

from materials.btf.directions import to_vector
from materials.btf.lafortune import (
    LOBES,
    PARAMS_PER_TEXEL,
    initial_params,
    join_params,
    lafortune_eval,
    split_params,
)
from models.brdf.train import deterministic_torch
from models.btf.lafortune import FitResult, fit_lafortune, normal_equations


@pytest.fixture(scope="module", autouse=True)
def one_thread() -> Iterator[None]:
    """Fits run as the job kinds run them (one thread, deterministic algorithms)."""
    with deterministic_torch():
        yield


def _pairs(seed: int, n: int = 300, max_theta: float = 75.0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` light/view pairs, uniform in solid angle up to ``max_theta`` degrees."""
    rng = np.random.default_rng(seed)
    lowest = np.cos(np.radians(max_theta))

    def one() -> np.ndarray:
        theta = np.degrees(np.arccos(rng.uniform(lowest, 1.0, n)))
        return to_vector(theta, rng.uniform(0.0, 360.0, n))

    return one(), one()


def _true_params(texels: int = 8, seed: int = 7) -> np.ndarray:
    """Diffuse plus a mirror lobe (n = 12) and a retro-reflection lobe (n = 3), symmetric
    ``M``, random colours; the other two lobes are off (no colour)."""
    rng = np.random.default_rng(seed)
    m = np.zeros((texels, LOBES, 3, 3))
    n = np.ones((texels, LOBES))
    rho_s = np.zeros((texels, LOBES, 3))
    m[:, 0], n[:, 0] = np.diag([-1.0, -1.0, 1.0]), 12.0
    m[:, 1], n[:, 1] = 0.9 * np.eye(3), 3.0
    rho_s[:, 0] = rng.uniform(0.2, 0.6, (texels, 3))
    rho_s[:, 1] = rng.uniform(0.05, 0.2, (texels, 3))
    return join_params(rng.uniform(0.05, 0.3, (texels, 3)), m, n, rho_s)


@pytest.fixture(scope="module")
def synthetic(
    one_thread: None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, FitResult]:
    truth = _true_params()
    wi, wo = _pairs(11)
    values = lafortune_eval(truth, wi, wo)
    return truth, values, wi, wo, fit_lafortune(values, wi, wo)


def test01_recovers_a_synthetic_lafortune_texel(
    synthetic: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, FitResult],
) -> None:
    """Reference: data made by the model with known parameters (fitted from
    ``initial_params``, whose lobes differ: n = 20, 4, 8, 2). Lobes may permute, so compare
    the function, at the fitted pairs and at fresh ones, and the diffuse colour."""
    truth, values, wi, wo, result = synthetic
    assert result.params.shape == (8, PARAMS_PER_TEXEL) and result.params.dtype == np.float32
    assert result.l1.shape == (8,) and result.iterations == 40
    scale = np.abs(values).mean(axis=(1, 2))
    fitted = lafortune_eval(result.params, wi, wo)
    np.testing.assert_allclose(result.l1, np.abs(fitted - values).mean(axis=(1, 2)), rtol=1e-9)
    assert (result.l1 / scale).max() < 1e-3
    wi2, wo2 = _pairs(12)
    held_out = lafortune_eval(truth, wi2, wo2)
    error = np.abs(lafortune_eval(result.params, wi2, wo2) - held_out).mean(axis=(1, 2))
    assert (error / np.abs(held_out).mean(axis=(1, 2))).max() < 1e-3
    np.testing.assert_allclose(result.params[:, :3], truth[:, :3], rtol=0.03)


def test02_lambertian_data_fits_to_the_diffuse_term() -> None:
    """Reference: a flat Lambertian plane, ``albedo / pi * wi.z`` (the UBO2014 convention);
    the fit's diffuse colour is ``albedo / pi`` and the lobes add next to nothing."""
    wi, wo = _pairs(21)
    albedo = np.array([[0.8, 0.5, 0.2], [0.05, 0.05, 0.05], [0.3, 0.6, 0.9]])
    values = albedo[:, None, :] / np.pi * wi[None, :, 2, None]
    result = fit_lafortune(values, wi, wo)
    np.testing.assert_allclose(result.params[:, :3], albedo / np.pi, rtol=1e-3)
    rho_d = np.zeros((3, PARAMS_PER_TEXEL))
    rho_d[:, :3] = result.params[:, :3]
    lobes = lafortune_eval(result.params, wi, wo) - lafortune_eval(rho_d, wi, wo)
    assert np.abs(lobes).max() < 1e-4 * values.mean()
    assert (result.l1 / values.mean(axis=(1, 2))).max() < 1e-4


def test03_zero_and_constant_data_stay_finite() -> None:
    """Reference: degenerate texels (all zero: no colour to give the lobes a gradient; a
    constant BTF) must give finite parameters and errors, zero data exactly zero colour."""
    wi, wo = _pairs(31, n=60)
    values = np.zeros((3, 60, 3))
    values[1] = 0.3
    values[2] = [0.0, 1e-9, 2.0]
    result = fit_lafortune(values, wi, wo, iterations=20)
    assert np.isfinite(result.params).all() and np.isfinite(result.l1).all()
    rho_d, _, _, rho_s = split_params(result.params[0])
    assert not rho_d.any() and not rho_s.any() and result.l1[0] == 0.0
    assert result.l1[1] < 0.3  # better than nothing


def test04_deterministic_and_independent_of_chunking(
    synthetic: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, FitResult],
) -> None:
    """Reference: the fit itself. No randomness, so a second run gives the same bytes. Each
    texel is fitted on its own, so chunks of 3 texels fit the same model; only round-off may
    differ, because chunking changes how BLAS batches the sums (Intel and AMD differ here).

    Tolerances, from what the fit returns: parameters are stored as float32, so the model a
    texel gets is defined to float32 resolution (eps32 = 1.19e-7) of its largest parameter;
    the off lobes' matrices (no colour) are not fixed by the data, only by the damping, so
    round-off moves them most, and the bound is per texel, not per entry. The model's values
    and the per-texel L1 (a mean of ``|f - y|``, so it moves by at most ``max |df|``) are held
    to eps32 of the data's largest value. Measured differences are 1e-11 of these bounds'
    scale (AMD EPYC, chunks of 1 and 3); a chunking bug (texels mixed up, a chunk refitted
    from the wrong start) moves them by O(1)."""
    _, values, wi, wo, result = synthetic
    fractions: list[float] = []
    again = fit_lafortune(values, wi, wo, progress=fractions.append)
    assert again.params.tobytes() == result.params.tobytes()
    assert again.l1.tobytes() == result.l1.tobytes()
    assert fractions[-1] == 1.0 and fractions == sorted(fractions) and len(fractions) > 40
    eps32 = float(np.finfo(np.float32).eps)
    scale = float(np.abs(values).max())
    for chunk in (1, 3):
        chunked = fit_lafortune(values, wi, wo, chunk=chunk)
        per_texel = eps32 * np.abs(result.params).max(axis=1, keepdims=True)
        assert np.all(np.abs(chunked.params - result.params) <= per_texel), chunk
        np.testing.assert_allclose(
            lafortune_eval(chunked.params, wi, wo),
            lafortune_eval(result.params, wi, wo),
            rtol=0,
            atol=eps32 * scale,
        )
        np.testing.assert_allclose(chunked.l1, result.l1, rtol=0, atol=eps32 * scale)


def _model_torch(p: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """The model written out directly for one texel ``(55,)``: ``(S, 3)``."""
    out = p[0:3] * wi[:, 2:3]
    for j in range(LOBES):
        o = 3 + 13 * j
        m = p[o : o + 9].reshape(3, 3)
        base = torch.einsum("sa,ab,sb->s", wo, m, wi)
        lobe = torch.clamp(base, min=0.0) ** torch.clamp(p[o + 9], min=1.0)
        out = out + wi[:, 2:3] * lobe[:, None] * p[o + 10 : o + 13]
    return out


# torch's forward-mode AD loads its decompositions through the deprecated torch.jit.script
@pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")
def test05_analytic_normal_equations_match_jacfwd() -> None:
    """Reference: ``torch.func.jacfwd`` of the model written out directly: ``J^T J``,
    ``J^T r`` and the squared residuals of the analytic, feature-based assembly agree."""
    rng = np.random.default_rng(41)
    wi_np, wo_np = _pairs(42, n=200)  # more than one block of pairs
    a = rng.normal(size=(4, LOBES, 3, 3))
    params_np = join_params(
        rng.uniform(0, 0.3, (4, 3)),
        0.6 * a + np.diag([-1.0, -1.0, 1.0]),  # asymmetric; some bases negative
        rng.uniform(1.5, 9.0, (4, LOBES)),
        rng.uniform(-0.2, 0.5, (4, LOBES, 3)),
    )
    params = torch.from_numpy(params_np)
    wi, wo = torch.from_numpy(wi_np), torch.from_numpy(wo_np)
    values = torch.from_numpy(rng.uniform(0.0, 0.5, (4, 200, 3)))
    jtj, jtr, sse = normal_equations(params, values, wi, wo)

    def residual(p: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return (_model_torch(p, wi, wo) - y).reshape(-1)

    jac = torch.func.vmap(torch.func.jacfwd(residual), in_dims=(0, 0))(params, values)
    r = torch.func.vmap(residual)(params, values)
    assert jac.shape == (4, 600, 55)
    torch.testing.assert_close(jtj, jac.transpose(1, 2) @ jac, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(jtr, (jac.transpose(1, 2) @ r[..., None])[..., 0])
    torch.testing.assert_close(sse, (r * r).sum(dim=1))


def test06_refuses_bad_input() -> None:
    """Reference: the documented shapes; an explicit ``init`` is used as given."""
    wi, wo = _pairs(51, n=10)
    values = np.full((2, 10, 3), 0.1)
    with pytest.raises(ValueError, match=r"values must be \(T, 10, 3\)"):
        fit_lafortune(values[:, :9], wi, wo)
    with pytest.raises(ValueError, match="init must be"):
        fit_lafortune(values, wi, wo, init=np.zeros((3, 55)))
    with pytest.raises(ValueError, match="finite"):
        fit_lafortune(values * np.nan, wi, wo)
    start = initial_params(np.full((2, 3), 0.2))
    same = fit_lafortune(values, wi, wo, iterations=0, init=start)
    np.testing.assert_allclose(same.params, start, rtol=1e-7)  # float32: half an ulp, 6e-8
