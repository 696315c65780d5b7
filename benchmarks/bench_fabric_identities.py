"""Projected-area identities of the fabric aggregate (Eq. 5), and the light it loses.

Over whole tiles, a height field's visible projected area is exactly ``cos theta`` in any
direction, so ``A_P(wo) / cos theta_o`` and ``A_in(wi) / cos theta_i`` must be 1 (Chen et
al. 2024, Eq. 5). The ratios below are means over ``--seeds`` independent estimates at
``--samples`` samples each (Dr.Jit backend, independent sampling, a 2-tile footprint, the
default march), with the standard error of that mean. Before the watertight height field
(issue 12) they were 0.86-0.98.

Run: ``.venv/bin/python benchmarks/bench_fabric_identities.py [--samples 16384 --seeds 8]``
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.fabric.aggregate import FootprintQueries, estimate  # noqa: E402
from materials.fabric.params import FabricParams  # noqa: E402
from materials.fabric.patterns import PATTERNS  # noqa: E402

THETAS = (30.0, 45.0, 60.0, 70.0, 80.0)


def direction(theta: float, phi: float) -> np.ndarray:
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=16384)
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args()
    head = " | ".join(f"{t:g} deg" for t in THETAS)
    print(f"| pattern | beta | ratio | {head} |")
    print("| --- | --- | --- | " + " | ".join("---" for _ in THETAS) + " |")
    for name in ("plain", "twill_3x3", "satin_5x5"):
        for beta in (0.5, 1.0, 2.0):
            params = FabricParams(PATTERNS[name], beta=beta, u_max_deg=30.0, psi_deg=20.0)
            wo = np.stack([direction(t, 25.0) for t in THETAS])
            wi = np.stack([direction(t, 160.0) for t in THETAS])
            q = FootprintQueries(np.full((len(THETAS), 2), 0.31), np.full(len(THETAS), 2.0), wi, wo)
            runs = [
                estimate(params, q, samples=args.samples, sampler="independent", seed=s,
                         backend="drjit")
                for s in range(args.seeds)
            ]  # fmt: skip
            for attr, w, label in (("area", wo, "A_P / cos_o"), ("area_in", wi, "A_in / cos_i")):
                v = np.stack([getattr(r, attr) for r in runs]) / w[:, 2]
                m, e = v.mean(axis=0), v.std(axis=0, ddof=1) / math.sqrt(len(runs))
                cells = " | ".join(f"{a:.3f} +- {b:.3f}" for a, b in zip(m, e, strict=True))
                print(f"| {name} | {beta:g} | {label} | {cells} |")
    print(f"\ncommand: .venv/bin/python benchmarks/bench_fabric_identities.py "
          f"--samples {args.samples} --seeds {args.seeds}")  # fmt: skip


if __name__ == "__main__":
    main()
