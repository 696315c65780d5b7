"""The Mitsuba loader: variant choice, loud fallback, and reproducibility across processes.

These run in child processes because a Mitsuba variant is process-global and cached.
Oracles: the variant Mitsuba reports, Python's warning machinery, and sha256 of the bytes of
the same render made by two independent processes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]

RENDER = """
import hashlib, json, warnings
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    from materials.backend import active_variant, load_mitsuba
    mi = load_mitsuba()
from evaluators.render.kind import plan_passes, render_passes
from evaluators.render.scenes import SceneSetup, build_scene
scene = mi.load_dict(build_scene("sphere_env", mi, {"type": "roughconductor"},
                                 SceneSetup((16, 12), 4, 4)))
img = render_passes(mi, scene, [2, 2], [7, 8])
print(json.dumps({"variant": active_variant(), "mitsuba_variant": mi.variant(),
                  "warnings": [str(w.message) for w in caught],
                  "sha": hashlib.sha256(img.tobytes()).hexdigest()}))
"""


def run_child(env_overrides: dict[str, str]) -> dict:
    env = {**os.environ, **env_overrides}
    proc = subprocess.run(
        [sys.executable, "-c", RENDER],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test01_llvm_variant_and_same_bytes_in_two_processes() -> None:
    from materials.backend import DEFAULT_LIBLLVM

    a, b = run_child({}), run_child({})
    # `make setup` installs libLLVM-19; without it the variant depends on what else exists.
    assert a["variant"] == a["mitsuba_variant"], a
    if Path(DEFAULT_LIBLLVM).is_file():
        assert a["variant"] == "llvm_ad_rgb", a["warnings"]
    assert a["sha"] == b["sha"]


def test02_loud_fallback_to_scalar() -> None:
    out = run_child({"DRJIT_LIBLLVM_PATH": "/nonexistent/libLLVM.so"})
    assert out["variant"] == out["mitsuba_variant"] == "scalar_rgb"
    assert any("falling back to 'scalar_rgb'" in w for w in out["warnings"])
