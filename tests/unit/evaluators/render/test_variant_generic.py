"""Every Python BSDF, integrator and fused kernel takes its types from the active Mitsuba
variant, so that it runs on ``cuda_ad_rgb`` as on ``llvm_ad_rgb`` (issue 29, section 4).

Two oracles, since this machine has no GPU:

- a static guard: no module of ours names a Dr.Jit backend (``drjit.llvm``,
  ``drjit.cuda``) or sets a variant, except :mod:`materials.backend`, the one loader; and
  no variant test accepts LLVM without CUDA;
- the same code path a worker runs (``MATFORGE_VARIANT`` read by the settings, then
  :func:`service.workers.backend.start_backend`), in a child process per variant: under an
  explicitly chosen ``llvm_ad_rgb`` every plugin class subclasses that variant's
  ``mi.BSDF`` / ``mi.SamplingIntegrator`` and the fused kernels' array types are that
  variant's (``mi.Float``, ``mi.Float16``, the backend module of
  :func:`materials.backend.jit_backend`); under ``scalar_rgb`` each refuses by name.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[4]
# Not benchmarks/: some measure the CPU's arithmetic on purpose and ask for LLVM by name.
PACKAGES = ("jobapi", "service", "storage", "materials", "models", "generators", "evaluators",
            "matforge", "scripts")  # fmt: skip
BACKEND_MODULE = REPO / "materials" / "backend.py"
# Code that names a backend (a mention in ``double backticks`` in a docstring is prose).
NAMES_BACKEND = re.compile(r"\bdrjit\.(llvm|cuda)\b(?!``)|\bdr\.(llvm|cuda)\.|set_variant\(")
LLVM_ONLY = re.compile(r"startswith\(\s*[\"']llvm[_a-z]*[\"']\s*\)")

CHILD = r"""
import json, sys
from service.settings import Settings
from service.workers.backend import start_backend
variant = start_backend(Settings.from_env({"MATFORGE_VARIANT": sys.argv[1]}))
from materials.backend import jit_backend, load_mitsuba
mi = load_mitsuba()
from evaluators.render.bsdfs import PLUGINS
from evaluators.render.integrators import SPECIALISED
out = {"variant": variant, "mitsuba": mi.variant(), "plugins": {}, "kernels": {},
       "modules": len(PLUGINS) + len(SPECIALISED)}
for mod in (*PLUGINS, *SPECIALISED):
    name = mod.__name__.rsplit(".", 1)[-1]
    register = next(getattr(mod, f) for f in dir(mod)
                    if f.startswith("register_") and f != "register_vectorised_bsdf"
                    and f != "register_vectorised_integrator")
    base = mi.BSDF if mod in PLUGINS else mi.SamplingIntegrator
    try:
        cls = register(mi)
        # a factory (external_onnx: the BRDF or the BTF class by kind) lists what it makes
        made = getattr(cls, "variants", (cls,))
        out["plugins"][name] = bool(made) and all(issubclass(c, base) for c in made)
    except RuntimeError as exc:
        out["plugins"][name] = "refused: " + str(exc)
def kernel(label, fn):
    try:
        out["kernels"][label] = bool(fn())
    except Exception as exc:  # under scalar_rgb: a refusal, or no JIT array at all
        out["kernels"][label] = "refused: " + str(exc)
from materials.fabric import aggregate_drjit
kernel("fabric estimator", lambda: aggregate_drjit.DrJitOps().Float is jit_backend(mi).Float)
from models.btf.fused import _float16_type
kernel("btf half textures", lambda: _float16_type(mi) is mi.Float16)
from models.fused_mlp import DenseLayer, fused_mlp
import numpy as np
layer = DenseLayer(np.ones((2, 3), np.float32), np.zeros(2, np.float32), "relu")
kernel("fused mlp", lambda: type(fused_mlp([layer], [mi.Float(1.0), mi.Float(2.0), 0.5])[0])
       is mi.Float)
print(json.dumps(out))
"""


def _sources() -> list[Path]:
    return [p for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))]


def test01_no_module_names_a_backend_but_the_loader() -> None:
    offenders = []
    for path in _sources():
        if path == BACKEND_MODULE:
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            code = line.split("#", 1)[0]
            if NAMES_BACKEND.search(code) or LLVM_ONLY.search(code):
                offenders.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert not offenders, "backend-specific code outside materials/backend.py:\n" + "\n".join(
        offenders
    )


def test02_guard_catches_what_it_is_for() -> None:
    for bad in ("import drjit.llvm as llvm", "from drjit.cuda import Float",
                "x = dr.llvm.Float(1)", "mi.set_variant('llvm_ad_rgb')",
                "if mi.variant().startswith('llvm_'):"):  # fmt: skip
        assert NAMES_BACKEND.search(bad) or LLVM_ONLY.search(bad), bad
    assert not LLVM_ONLY.search('variant.startswith(("llvm_", "cuda_"))')


def _child(variant: str) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, variant],
        cwd=REPO, env=dict(os.environ), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(
    not Path("/usr/lib/x86_64-linux-gnu/libLLVM-19.so").is_file(), reason="needs libLLVM-19"
)
def test03_every_plugin_and_kernel_takes_the_chosen_variants_types() -> None:
    out = _child("llvm_ad_rgb")
    assert out["variant"] == out["mitsuba"] == "llvm_ad_rgb"
    # every BSDF and integrator module of the registry, none skipped (13 at the time of
    # writing: 10 built-in BSDFs and integrators plus the external MLP, MLP BTF and ONNX)
    assert out["modules"] >= 13 and len(out["plugins"]) == out["modules"], out
    assert all(v is True for v in out["plugins"].values()), out
    assert all(v is True for v in out["kernels"].values()), out


def test04_a_scalar_variant_is_refused_by_every_plugin_by_name() -> None:
    out = _child("scalar_rgb")
    assert out["variant"] == "scalar_rgb"
    for name, v in {
        **out["plugins"],
        "fabric estimator": out["kernels"]["fabric estimator"],
    }.items():
        assert isinstance(v, str) and v.startswith("refused: ") and "scalar_rgb" in v, (name, v)
