"""The procedural microstructure: tiny examples transformed and distributed over the plane
(Xing et al. 2024, Sec. 6.1-6.2).

**Transforms** (Sec. 6.1). An instance of the example is placed with a 2x2 linear map ``A``
(scale, shear, rotation, mirror: the upper-left block of the paper's ``M``) and a tilt
offset ``o`` (the paper's ``t_x, t_y``, an offset of the projected normals). Positions map
as ``u_local = A^-1 (u - c) + n / 2`` for an instance centred at ``c``; the height field is
carried along, so slopes map as ``s = A^-T s_local + o`` and an NDF image as
``D(s) = |det A| D_local(A^T (s - o))``. A rotation therefore rotates the NDF image.

**Distributions** (Sec. 6.2):

- ``tiled``: one transform for the whole plane, the example repeated without overlap:
  ``u_local = (A^-1 u) mod n``;
- ``stochastic``: instances on a jittered grid of cells of side ``spacing`` (texels), each
  with a seeded random rotation, mirror and scale -- the paper's "noise map" of example
  centres and transforms, here a seeded table that repeats every ``period`` cells. Where
  instances overlap, Fig. 3's rule decides: each grid cell is split into four sub-regions,
  and a sub-region belongs to the covering instance whose centre is nearest to the
  sub-region's centre.

Units: global and local positions in texels of the example; the plane is unbounded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from materials.glints.lobes import bilinear


@dataclass(frozen=True)
class Transform:
    """``A`` (2x2, positions) and the normal-space offset ``o`` (module docstring)."""

    a: np.ndarray = field(default_factory=lambda: np.eye(2))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @classmethod
    def compose(
        cls,
        *,
        scale: tuple[float, float] = (1.0, 1.0),
        shear: tuple[float, float] = (0.0, 0.0),
        rotation_deg: float = 0.0,
        mirror: bool = False,
        offset: tuple[float, float] = (0.0, 0.0),
    ) -> Transform:
        """``A = R(rotation) [[s_x, h_x], [h_y, s_y]] diag(-1 if mirror, 1)``."""
        if scale[0] <= 0 or scale[1] <= 0:
            raise ValueError(f"scales must be > 0, got {scale}")
        th = math.radians(rotation_deg)
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        sh = np.array([[scale[0], shear[0]], [shear[1], scale[1]]])
        mir = np.diag([-1.0 if mirror else 1.0, 1.0])
        a = rot @ sh @ mir
        if abs(np.linalg.det(a)) < 1e-6:
            raise ValueError("the transform is singular (shear too strong for the scale)")
        return cls(a=a, offset=np.asarray(offset, dtype=np.float64))

    @property
    def inverse(self) -> np.ndarray:
        return np.linalg.inv(self.a)

    def slopes_to_global(self, s_local: np.ndarray) -> np.ndarray:
        """``s = A^-T s_local + o`` for ``(..., 2)`` arrays."""
        return s_local @ self.inverse + self.offset

    def slopes_to_local(self, s: np.ndarray) -> np.ndarray:
        """``s_local = A^T (s - o)`` for ``(..., 2)`` arrays."""
        return (s - self.offset) @ self.a

    @property
    def density_scale(self) -> float:
        """``|det A|``: ``D(s) = |det A| D_local(s_local)``."""
        return float(abs(np.linalg.det(self.a)))


@dataclass(frozen=True)
class Instance:
    """One placed example: centre ``c`` (global texels) and its transform."""

    centre: np.ndarray
    transform: Transform

    def to_local(self, u: np.ndarray, n: int) -> np.ndarray:
        """Global ``(..., 2)`` positions in the instance's example texels."""
        return (u - self.centre) @ self.transform.inverse.T + 0.5 * n

    def covers(self, u: np.ndarray, n: int) -> np.ndarray:
        """Whether each global position lies on the instance's example square."""
        loc = self.to_local(u, n)
        return np.all((loc >= 0.0) & (loc < n), axis=-1)


@dataclass(frozen=True)
class Distribution:
    """How instances cover the plane: ``kind`` ``"tiled"`` or ``"stochastic"``.

    ``tiled`` uses ``transform``; ``stochastic`` draws, per grid cell of side ``spacing``, a
    centre jitter up to ``jitter`` cells, a rotation in ``[0, 360)`` degrees (if ``rotate``),
    a mirror (if ``mirror``) and an isotropic scale in ``scale_range``, from ``seed``;
    the table repeats every ``period`` cells.
    """

    kind: str = "tiled"
    transform: Transform = field(default_factory=Transform)
    spacing: float = 0.0
    jitter: float = 0.25
    rotate: bool = True
    mirror: bool = True
    scale_range: tuple[float, float] = (1.0, 1.0)
    period: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in ("tiled", "stochastic"):
            raise ValueError(f"distribution kind must be tiled or stochastic, not {self.kind!r}")


class Surface:
    """A procedural microstructure: an ``(n, n, 3)`` example under a :class:`Distribution`.

    ``normal_at(u)`` gives the projected normal of the surface at global positions, which is
    what :func:`export_normal_map` samples for the explicit reference (Fig. 9); the P-NDF
    evaluators use :meth:`instances_near` and :meth:`owner`.
    """

    def __init__(self, normals: np.ndarray, distribution: Distribution) -> None:
        self.normals = np.asarray(normals, dtype=np.float32)
        self.n = int(self.normals.shape[0])
        self.dist = distribution
        if distribution.kind == "stochastic":
            spacing = distribution.spacing or 0.75 * self.n * min(distribution.scale_range)
            self.spacing = float(spacing)
            self._table = self._draw_table()

    # -- the stochastic table ------------------------------------------------------------
    def _draw_table(self) -> list[list[Instance]]:
        d = self.dist
        rng = np.random.default_rng(np.random.SeedSequence([d.seed, 0x6C1]))
        table = []
        for _cy in range(d.period):
            row = []
            for _cx in range(d.period):
                jit = rng.uniform(-d.jitter, d.jitter, 2)
                rot = rng.uniform(0.0, 360.0) if d.rotate else 0.0
                mir = bool(rng.integers(0, 2)) if d.mirror else False
                sc = rng.uniform(*d.scale_range)
                row.append(
                    Instance(
                        centre=jit,  # in cells, relative to the cell centre
                        transform=Transform.compose(scale=(sc, sc), rotation_deg=rot, mirror=mir),
                    )
                )
            table.append(row)
        return table

    @property
    def table(self) -> list[list[Instance]]:
        """The stochastic table: ``period x period`` instances, centres as jitter in cells
        relative to the cell centre (what :func:`materials.glints.pndf_drjit.jit_placement`
        uploads)."""
        return self._table

    def _cell_instance(self, cx: int, cy: int) -> Instance:
        p = self.dist.period
        proto = self._table[cy % p][cx % p]
        centre = (np.array([cx, cy], dtype=np.float64) + 0.5 + proto.centre) * self.spacing
        return Instance(centre=centre, transform=proto.transform)

    def instances_near(self, lo: np.ndarray, hi: np.ndarray) -> list[Instance]:
        """Stochastic instances whose example square may meet the box ``[lo, hi]``."""
        reach = 0.75 * self.n * max(self.dist.scale_range) + self.dist.jitter * self.spacing
        c0 = np.floor((np.asarray(lo) - reach) / self.spacing).astype(int)
        c1 = np.floor((np.asarray(hi) + reach) / self.spacing).astype(int)
        return [
            self._cell_instance(cx, cy)
            for cy in range(c0[1], c1[1] + 1)
            for cx in range(c0[0], c1[0] + 1)
        ]

    def owner(self, u: np.ndarray) -> list[tuple[Instance, np.ndarray]]:
        """Fig. 3's occlusion rule for global positions ``u`` ``(N, 2)``: the instances that
        own them, as ``[(instance, mask over u)]`` (a position no instance covers is in no
        mask)."""
        u = np.asarray(u, dtype=np.float64)
        cell = np.floor(u / self.spacing)
        quad = np.floor((u / self.spacing - cell) * 2.0)
        sub_centre = (cell + (quad + 0.5) / 2.0) * self.spacing
        cands = self.instances_near(u.min(axis=0), u.max(axis=0))
        best = np.full(len(u), -1)
        best_d = np.full(len(u), np.inf)
        for j, inst in enumerate(cands):
            cov = inst.covers(u, self.n)
            d = np.linalg.norm(sub_centre - inst.centre, axis=-1)
            take = cov & (d < best_d)
            best[take], best_d[take] = j, d[take]
        return [(inst, best == j) for j, inst in enumerate(cands) if np.any(best == j)]

    # -- normals -------------------------------------------------------------------------
    def normal_at(self, u: np.ndarray) -> np.ndarray:
        """Projected normals ``(N, 2)`` of the surface at global positions ``u`` ``(N, 2)``
        (0, i.e. flat, where no stochastic instance covers the point)."""
        u = np.asarray(u, dtype=np.float64)
        if self.dist.kind == "tiled":
            t = self.dist.transform
            loc = (u @ t.inverse.T) % self.n
            s, _ = bilinear(self.normals, loc)
            return t.slopes_to_global(s)
        out = np.zeros((len(u), 2))
        for inst, mask in self.owner(u):
            s, _ = bilinear(self.normals, inst.to_local(u[mask], self.n))
            out[mask] = inst.transform.slopes_to_global(s)
        return out


#: Side of the blocks :func:`export_normal_map` evaluates at a time (export texels).
EXPORT_BLOCK = 128


def export_normal_map(
    surface: Surface,
    size: int,
    *,
    oversample: int = 1,
    origin: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """The explicit normal map of ``surface`` over ``[origin, origin + size)^2`` (global
    texels) at ``oversample`` export texels per example texel: ``(size * oversample,) * 2 +
    (3,)`` float32 unit normals (z from the projected normal, clipped inside the unit disk).

    This is what the Yan et al. reference renders (Xing et al. 2024, Fig. 9: "we explicitly
    export the microstructure"). Exported at one texel per example texel, the bilinear
    re-interpolation of a transformed or offset example smooths it (its texel centres no
    longer fall on the example's); oversampling by 4 keeps the exported field within a few
    per cent of the procedural one. Export texel ``(i, j)`` sits at global
    ``origin + ((j, i) + 0.5) / oversample``.
    """
    k = int(oversample)
    side = size * k
    grid = np.empty((side, side, 2))
    # In blocks of EXPORT_BLOCK^2 texels: a stochastic surface's owner test visits every
    # instance near the positions it is given, so one call over the whole map costs
    # (texels x instances); per block, only the block's few dozen. Each position's normal
    # does not depend on the others, so the blocks give the same values.
    for i0 in range(0, side, EXPORT_BLOCK):
        for j0 in range(0, side, EXPORT_BLOCK):
            i1, j1 = min(i0 + EXPORT_BLOCK, side), min(j0 + EXPORT_BLOCK, side)
            y, x = (np.mgrid[i0:i1, j0:j1].astype(np.float64) + 0.5) / k
            u = np.stack([x.ravel() + origin[0], y.ravel() + origin[1]], axis=1)
            grid[i0:i1, j0:j1] = surface.normal_at(u).reshape(i1 - i0, j1 - j0, 2)
    s = grid.reshape(-1, 2)
    r2 = (s * s).sum(axis=1)
    s = s * np.where(r2 > 1.0 - 1e-6, np.sqrt((1.0 - 1e-6) / np.maximum(r2, 1e-12)), 1.0)[:, None]
    nz = np.sqrt(1.0 - (s * s).sum(axis=1))
    return np.concatenate([s, nz[:, None]], axis=1).reshape(side, side, 3).astype(np.float32)
