"""``benchmarks/bench_glint_figures.py`` (and its recipe ``scripts/glint_figures.yaml``) at
tiny size: 16 x 12 pixels, 2 spp (references 4), 16 texels per uv, NDF images of 16 cells.

Runs the script as a user would (a subprocess; ``--only fig1`` keeps Figs. 10-12, the
steps they use and Fig. 9's stochastic render that Fig. 10 shows; Figs. 8 and 9 share their
code path with Fig. 11's tiny-against-Yan scores, and are left out to save time). Takes
50 s on the loaded 2-core machine (load average 10; mostly kernel compilation).

Oracles: each figure's PNG has the size of its grid of panels (``rows x columns`` tiles of
16 x 12 and 2-pixel gaps); every FLIP is in [0, 1] and PSNR finite; the transforms of
Fig. 11 each change the image against the tiling (FLIP above 0); the three noise maps of
Fig. 12 are three different layouts.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
W, H, GAP = 16, 12, 2


def _size(rows: int, cols: int) -> tuple[int, int]:
    return cols * (W + GAP) - GAP, rows * (H + GAP) - GAP


@pytest.mark.slow
def test01_figure_script_at_tiny_size(tmp_path: Path) -> None:
    out, figs = tmp_path / "figures.json", tmp_path / "figures"
    tiny = {"width": W, "height": H, "spp": 2, "ref_spp": 4, "texels": 16, "ndf": 16}
    sizes = [f"--var={k}={v}" for k, v in tiny.items()]
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_glint_figures.py"),
           "--data-dir", str(tmp_path / "data"), "--out", str(out), "--figures", str(figs),
           "--only", "fig1", *sizes]  # fmt: skip
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=540)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    res = json.loads(out.read_text())
    # Each panel: the grid of its tiles.
    for name, (rows, cols) in {"fig10": (1, 5), "fig11": (3, 5), "fig12": (2, 3)}.items():
        with Image.open(figs / f"{name}.png") as im:
            assert im.size == _size(rows, cols), (name, im.size)
    assert not (figs / "fig8.png").exists()  # not asked for
    for r in res["fig11"].values():
        assert 0.0 <= r["flip_vs_yan"] <= 1.0 and math.isfinite(r["psnr_vs_yan"]), r
        if r["flip_vs_tiling"] is not None:
            assert r["flip_vs_tiling"] > 0.0, r
    assert res["fig11"]["tile"]["flip_vs_tiling"] is None
    assert all(0.0 <= v <= 1.0 for v in res["fig12"]["flip_vs_map0"].values())
    with Image.open(figs / "fig12.png") as im:
        top = np.asarray(im.convert("RGB"))[:H]
    maps = [top[:, j * (W + GAP) : j * (W + GAP) + W].astype(int) for j in range(3)]
    assert np.abs(maps[0] - maps[1]).sum() > 0 and np.abs(maps[1] - maps[2]).sum() > 0
    assert set(res["png_bytes"]) == {"fig10", "fig11", "fig12"}
