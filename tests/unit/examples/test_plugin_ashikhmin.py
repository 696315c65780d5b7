"""The physics of the plugin example (``examples/plugin-kind``): the Ashikhmin-Shirley BRDF
against closed forms and quadrature, and its fit against a table tabulated by matforge.

``brdf.py`` is loaded from its file, not imported as an installed package: putting the
example's folder on ``sys.path`` would let ``importlib.metadata`` find its entry point and
register the kind in every later test of the session.
"""

from __future__ import annotations

import importlib.util
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from evaluators.metrics.brdf import TableSampler, direction_pairs, sample_brdf
from materials.analytic import build_analytic
from materials.tabulate import tabulate_analytic

BRDF_PY = Path(__file__).resolve().parents[3] / "examples/plugin-kind/matforge_ashikhmin/brdf.py"


@pytest.fixture(scope="module")
def asb() -> types.ModuleType:
    name = "_matforge_ashikhmin_brdf_under_test"
    spec = importlib.util.spec_from_file_location(name, BRDF_PY)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while building
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)


def hemisphere_grid(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint rule over the upper hemisphere: ``(m * 2m, 3)`` directions and their solid
    angles (summing to 2 pi up to O(1/m^2))."""
    t = (np.arange(m) + 0.5) / m * (math.pi / 2)
    p = (np.arange(2 * m) + 0.5) / (2 * m) * (2 * math.pi)
    tt, pp = np.meshgrid(t, p, indexing="ij")
    w = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    dw = np.sin(tt) * (math.pi / 2 / m) * (2 * math.pi / (2 * m))
    return w.reshape(-1, 3), dw.ravel()


def incident(theta_deg: float, n: int) -> np.ndarray:
    a = math.radians(theta_deg)
    return np.broadcast_to(np.array([math.sin(a), 0.0, math.cos(a)]), (n, 3))


def test01_reciprocity(asb: types.ModuleType) -> None:
    m = asb.AshikhminShirley(rs=(0.04, 0.3, 0.9), rd=(0.7, 0.2, 0.5), n=35.0)
    wi, wo = direction_pairs(4096, seed=5, distribution="uniform")
    np.testing.assert_allclose(m.eval(wi, wo), m.eval(wo, wi), rtol=1e-12, atol=0)


def test02_closed_form_at_normal_incidence(asb: types.ModuleType) -> None:
    # wi = wo = z: h = z, h.k = 1, so F = Rs and the diffuse factors are (31/32)^2.
    rs, rd, n = np.array([0.1, 0.5, 0.9]), np.array([0.8, 0.4, 0.2]), 50.0
    m = asb.AshikhminShirley(rs=tuple(rs), rd=tuple(rd), n=n)
    z = np.array([[0.0, 0.0, 1.0]])
    expected = (n + 1) / (8 * math.pi) * rs + 28 / (23 * math.pi) * (31 / 32) ** 2 * rd * (1 - rs)
    np.testing.assert_allclose(m.eval(z, z)[0], expected, rtol=1e-12)
    below = np.array([[0.0, 0.6, -0.8]])
    assert np.all(m.eval(below, z) == 0) and np.all(m.eval(z, below) == 0)


def test03_diffuse_albedo_matches_its_closed_form(asb: types.ModuleType) -> None:
    # 28 / (23 pi) makes the diffuse albedo exactly 1 - (1 - cos(theta_i) / 2)^5 (x Rd (1 -
    # Rs)). The integrand is smooth: the midpoint rule at 300 x 600 is good to ~1e-5.
    wo, dw = hemisphere_grid(300)
    for theta in (0.0, 30.0, 60.0, 85.0):
        _, _, d = asb.terms(incident(theta, len(wo)), wo, 10.0)
        albedo = float(np.sum(d * wo[:, 2] * dw))
        assert albedo == pytest.approx(1 - (1 - math.cos(math.radians(theta)) / 2) ** 5, abs=1e-4)


def test04_energy_conservation(asb: types.ModuleType) -> None:
    # Directional albedo <= 1 for white Rd and any Rs, at every incidence: the lobes of
    # n <= 100 are >= 8 degrees wide, and the 400 x 800 grid's 0.2-degree steps resolve them
    # to well under the 2e-3 allowed.
    wo, dw = hemisphere_grid(400)
    for n in (1.0, 10.0, 100.0):
        for theta in (0.0, 60.0, 85.0):
            s, c5, d = asb.terms(incident(theta, len(wo)), wo, n)
            for rs in (0.0, 0.04, 0.5, 1.0):
                f = s * (rs + (1 - rs) * c5) + d * (1 - rs)
                albedo = float(np.sum(f * wo[:, 2] * dw))
                assert 0 < albedo <= 1 + 2e-3, (n, theta, rs, albedo)


def test05_fit_recovers_a_tabulated_material(asb: types.ModuleType) -> None:
    # The table is made by matforge's own tabulation (materials.tabulate: MERL bins, horizon
    # marking) and read back through its multilinear lookup; the fit sees only those values.
    # Tolerances: the 1-degree bins and the lookup's interpolation bias the specular peak by
    # under a percent (measured: n 0.5 %, Rs 0.3 %, Rd 0.02 %).
    true = asb.AshikhminShirley(rs=(0.04, 0.05, 0.06), rd=(0.6, 0.3, 0.1), n=200.0)
    table, _ = tabulate_analytic(true)
    wi, wo = direction_pairs(1 << 14, seed=7)
    ref = sample_brdf(TableSampler(table), wi, wo)
    keep = ~np.any(ref < 0, axis=1)
    fitted, loss = asb.fit(wi[keep], wo[keep], ref[keep], exponents=24)
    assert fitted.n == pytest.approx(200.0, rel=0.03)
    np.testing.assert_allclose(fitted.rs, true.rs, atol=0.004)
    np.testing.assert_allclose(fitted.rd, true.rd, atol=0.01)
    assert math.isfinite(loss) and loss >= 0
    # Deterministic: the same inputs give the same material.
    again, _ = asb.fit(wi[keep], wo[keep], ref[keep], exponents=24)
    assert again == fitted


@pytest.mark.parametrize(("alpha", "rel"), [(0.1, 0.03), (0.3, 0.08)])
def test06_beckmann_conductor_gives_walter_exponent(
    asb: types.ModuleType, alpha: float, rel: float
) -> None:
    # Independent reference: Walter et al. 2007 (Sec. 5.2) match a Phong lobe of exponent
    # n = 2 / alpha^2 - 2 to the Beckmann NDF of roughness alpha. The correspondence is
    # asymptotic (the lobes' shapes differ more as alpha grows): measured 1 % at 0.1 and
    # 5 % at 0.3, hence the tolerances. A conductor has no diffuse term.
    source = build_analytic({"model": "beckmann", "alpha": alpha, "material": "Au"})
    table, _ = tabulate_analytic(source)
    wi, wo = direction_pairs(1 << 14, seed=7)
    ref = sample_brdf(TableSampler(table), wi, wo)
    keep = ~np.any(ref < 0, axis=1)
    fitted, _ = asb.fit(wi[keep], wo[keep], ref[keep], exponents=24)
    assert fitted.n == pytest.approx(2 / alpha**2 - 2, rel=rel)
    assert max(fitted.rd) < 1e-3


def test07_bad_input(asb: types.ModuleType) -> None:
    with pytest.raises(ValueError, match="rs must be 3 values"):
        asb.AshikhminShirley(rs=(1.5, 0, 0), rd=(0, 0, 0), n=10.0)
    with pytest.raises(ValueError, match="n must be in"):
        asb.AshikhminShirley(rs=(0, 0, 0), rd=(0, 0, 0), n=0.5)
    wi, wo = direction_pairs(64, seed=1)
    with pytest.raises(ValueError, match="non-negative"):
        asb.fit(wi, wo, -np.ones((64, 3)))
    with pytest.raises(ValueError, match=r"must all be \(N, 3\)"):
        asb.fit(wi, wo, np.ones((63, 3)))
