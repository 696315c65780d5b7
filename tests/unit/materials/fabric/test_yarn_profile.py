"""``yarn_profile``: Jin et al.'s yarn (``"jin"``) against the default tapered one.

References, independent of the height-field code:

- **Steep facets, analytically.** Jin's profile has the slopes ``tan v`` across and
  ``tan u`` along, with ``v = 80 deg xi`` and ``u = u_max eta`` linear in the float's
  coordinates (``materials.fabric.yarn``), so at ``beta = 1`` the share of a float's
  projected area steeper than 70 degrees is a quadrature of
  ``tan^2 v + tan^2 u > tan^2 70`` over ``(xi, eta)``, the same for every float. Where
  ``yarn_profile = "jin"`` keeps Jin's slopes (``|xi|, |eta| <= 1 - JIN_TAPER``) the
  rasterised normals must give that share; over the whole float it may differ only by the
  closing band's area. The default profile must not pass the first check (the test can
  fail).
- **Projected area** (Eq. 5): a watertight height field has ``A_P(wo) = cos theta_o``
  over whole tiles, whatever its profile (as ``test_identities.py``), within 0.02.
- **Reciprocity** of the numerator of Eq. 3 with ``w = 1``, to rounding.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from materials.fabric import yarn
from materials.fabric.array_ops import NumpyOps
from materials.fabric.params import FabricParams, params_json
from materials.fabric.patterns import PATTERNS
from tests.helpers.fabric_identities import area_over_cosine, reciprocity_sides

OPS = NumpyOps()
STEEP = math.radians(70.0)
U_MAX = 30.0


def jin_steep_share(u_max_deg: float, reach: float) -> float:
    """Share of ``[-reach, reach]^2`` in ``(xi, eta)`` where Jin's slopes exceed
    ``tan 70 deg``: for each ``eta``, ``|xi|`` above ``x* = atan(sqrt(tan^2 70 -
    tan^2 u)) / 80 deg``; midpoint rule over ``eta`` (400,000 points)."""
    n = 400_000
    eta = (np.arange(n) + 0.5) / n * reach
    tan_u = np.tan(np.radians(u_max_deg) * eta)
    rest = np.maximum(math.tan(STEEP) ** 2 - tan_u**2, 0.0)
    x_star = np.arctan(np.sqrt(rest)) / yarn.ROLL_MAX
    return float(np.mean(np.clip(reach - x_star, 0.0, reach)) / reach)


def steep_shares(params: FabricParams, res: int) -> tuple[float, float]:
    """(inside Jin's reach, whole floats): measured shares of yarn pixels steeper than 70."""
    centres = (np.arange(res) + 0.5) / res
    t, s = np.meshgrid(centres, centres, indexing="ij")
    geo = yarn.YarnGeometry.from_params(params)
    tab = yarn.tables(OPS, geo)
    surf = yarn.surface(OPS, geo, tab, s, t)
    loc = yarn._locate(OPS, geo, tab, s, t)  # the float coordinates (xi, eta) only
    in_yarn = np.asarray(surf.warp | surf.weft)
    steep = np.asarray(surf.normal[2]) < math.cos(STEEP)
    reach = 1.0 - yarn.JIN_TAPER
    inner = in_yarn & (np.abs(loc.xi) <= reach) & (np.abs(loc.eta) <= reach)
    return float(steep[inner].mean()), float(steep[in_yarn].mean())


@pytest.mark.parametrize("name", ["plain", "twill_3x3", "satin_5x5"])
def test01_jin_profile_has_jins_share_of_steep_facets(name: str) -> None:
    reach = 1.0 - yarn.JIN_TAPER
    inner_ref = jin_steep_share(U_MAX, reach)
    whole_ref = jin_steep_share(U_MAX, 1.0)
    band = 1.0 - reach**2  # the closing band's share of a float's area
    jin = FabricParams(PATTERNS[name], u_max_deg=U_MAX, beta=1.0, yarn_profile="jin")
    inner, whole = steep_shares(jin, 1024)
    # 1024 pixels over <= 5 cells: >= 160 pixels across a yarn; the steep set's edges
    # cost at most a few pixels' share.
    assert abs(inner - inner_ref) <= 0.006, (inner, inner_ref)
    # Outside the reach anything may happen, on at most the band's area.
    assert inner_ref * reach**2 - 0.006 <= whole <= inner_ref * reach**2 + band + 0.006
    assert abs(whole - whole_ref) <= band + 0.006, (whole, whole_ref)
    # The default profile is a different yarn: its taper bends the normals from |xi| or
    # |eta| = 0.5 on, which this comparison sees.
    smooth = FabricParams(PATTERNS[name], u_max_deg=U_MAX, beta=1.0)
    inner_smooth, _ = steep_shares(smooth, 1024)
    assert abs(inner_smooth - inner_ref) > 0.03, (inner_smooth, inner_ref)


@pytest.mark.parametrize("name", ["plain", "twill_3x3", "satin_5x5"])
@pytest.mark.parametrize("beta", [0.7, 2.0])
def test02_projected_areas_are_cosines_with_jins_profile(name: str, beta: float) -> None:
    params = FabricParams(
        PATTERNS[name], beta=beta, u_max_deg=U_MAX, psi_deg=20.0, yarn_profile="jin"
    )
    for attr, (mean, err) in area_over_cosine(params, samples=131072).items():
        # The bar: 0.02 (1 % for the march's coarse steps at grazing angles, as in
        # test_identities.py, plus Monte Carlo error), and 4 standard errors besides.
        assert np.all(np.abs(mean - 1.0) <= 0.02), (attr, mean, err)
        assert np.all(np.abs(mean - 1.0) <= 4 * err + 0.01), (attr, mean, err)


@pytest.mark.parametrize("name", ["plain", "twill_3x3", "satin_5x5"])
def test03_reciprocity_with_jins_profile(name: str) -> None:
    params = FabricParams(PATTERNS[name], beta=1.0, u_max_deg=U_MAX, w=1.0, yarn_profile="jin")
    lhs, rhs = reciprocity_sides(params)
    np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-12)


def test04_profile_is_validated_and_the_default_keeps_its_string() -> None:
    with pytest.raises(ValueError, match="yarn_profile"):
        FabricParams("plain", yarn_profile="round")
    default = FabricParams("twill_3x3")
    assert "yarn_profile" not in json.loads(params_json(default))
    jin = default.replace(yarn_profile="jin")
    assert json.loads(params_json(jin))["yarn_profile"] == "jin"
    assert FabricParams(**json.loads(params_json(jin))) == jin
    # The two profiles agree inside Jin's reach of the taper and differ outside it.
    a, b = yarn.rasterize(default, 128), yarn.rasterize(jin, 128)
    assert not np.allclose(a.height, b.height)
    assert yarn.max_slope(jin) > yarn.max_slope(default)
    maps = b.normal.astype(np.float64)
    slope = np.hypot(maps[..., 0], maps[..., 1]) / maps[..., 2]
    assert slope.max() <= yarn.max_slope(jin) * (1 + 1e-4)
