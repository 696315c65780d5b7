"""The one place where matforge imports Mitsuba 3 (and with it Dr.Jit) and picks its variant.

Every module that needs Mitsuba or a Dr.Jit array type calls :func:`load_mitsuba` and uses
the module it returns (and :func:`jit_backend` for the Dr.Jit array types Mitsuba does not
re-export, e.g. ``Float64``); nothing else calls ``mitsuba.set_variant`` or imports
``drjit.llvm`` / ``drjit.cuda``, so every kernel follows the variant (a static test guards
it). It lives in ``materials`` because the Dr.Jit twins of the physics need a JIT backend
as much as the renderer does; Mitsuba *plugins* (BSDFs, integrators) live in
:mod:`evaluators.render`.

Which variant: a *choice* (:data:`VARIANT_CHOICES`), set once per process by the edge with
:func:`configure` from the ``MATFORGE_VARIANT`` setting (:mod:`service.settings`), and
resolved by the first :func:`load_mitsuba`:

- ``auto`` (the default): ``cuda_ad_rgb`` when Dr.Jit finds a CUDA device, else
  ``llvm_ad_rgb``, else the loud ``scalar_rgb`` fallback below;
- a variant's name: exactly that variant, or :class:`VariantUnavailable` (e.g.
  ``cuda_ad_rgb`` without a CUDA driver and device).

Why a loader at all: the fast CPU variant, ``llvm_ad_rgb``, JIT-compiles kernels through a
shared libLLVM that Dr.Jit finds at run time. On the Debian machines matforge targets, the
system's default libLLVM-15 aborts the whole process while compiling (``LLVM ERROR: Cannot
select ... fminimum``), so Dr.Jit has to be pointed at libLLVM-19 *before* ``mitsuba`` is
imported. Where no usable libLLVM exists, ``auto`` falls back to ``scalar_rgb`` (about 30x
slower) and says so loudly; the variant in use is written into every job's manifest.
"""

from __future__ import annotations

import importlib
import logging
import os
import subprocess
import sys
import threading
import types
import warnings
from pathlib import Path

log = logging.getLogger(__name__)

#: The variant used for all real work without a GPU: vectorised CPU rendering through LLVM.
PREFERRED_VARIANT = "llvm_ad_rgb"
#: The variant ``auto`` takes where Dr.Jit finds a CUDA device.
CUDA_VARIANT = "cuda_ad_rgb"
#: The variant used when the LLVM backend cannot start (no libLLVM, or a broken one).
FALLBACK_VARIANT = "scalar_rgb"
#: Debian's libLLVM-19 (``apt-get install libllvm19``), installed by ``make setup``.
DEFAULT_LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"

#: What :func:`configure` accepts: ``auto`` or one of the RGB variants matforge runs on.
VARIANT_CHOICES: tuple[str, ...] = ("auto", PREFERRED_VARIANT, CUDA_VARIANT, FALLBACK_VARIANT)

_lock = threading.RLock()
_module: types.ModuleType | None = None
_variant: str | None = None
# The process's choice (:func:`configure`); ``auto`` until the edge says otherwise.
_choice: str = "auto"
_libllvm: str | None = None
# Whether a load since the last change of choice settled it (later ``variant=None`` calls
# then return the module as it is, even after an explicit switch).
_settled = False


class VariantUnavailable(ImportError):
    """The Mitsuba variant that was asked for cannot run in this process (not built into
    Mitsuba, or its Dr.Jit backend finds no driver, device or libLLVM)."""


# A tiny render, run in a child process so that an LLVM abort (libLLVM-15 cannot select
# the ``fminimum`` that Mitsuba's kernels contain) cannot take this process down.
_PROBE = (
    "import mitsuba as mi\n"
    "mi.set_variant('llvm_ad_rgb')\n"
    "scene = mi.load_dict({'type': 'scene', 'integrator': {'type': 'path'},\n"
    "    'shape': {'type': 'sphere'},\n"
    "    'light': {'type': 'constant'}, 'sensor': {'type': 'perspective',\n"
    "    'film': {'type': 'hdrfilm', 'width': 4, 'height': 4}}})\n"
    "print(mi.render(scene, spp=1).numpy().sum())\n"
)


def _point_drjit_at_libllvm(libllvm_path: str) -> None:
    # Dr.Jit reads DRJIT_LIBLLVM_PATH when its LLVM backend initialises, i.e. when
    # ``mitsuba`` is imported; there is no API to pass the path. Setting a third-party
    # library's variable here is the one sanctioned exception to "the environment is read
    # in service/settings.py only" (see the module docstring for why it must happen here).
    if "DRJIT_LIBLLVM_PATH" not in os.environ and Path(libllvm_path).is_file():
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm_path


def _llvm_probe_ok(timeout_s: float = 120.0) -> bool:
    """Whether an LLVM kernel compiles and runs, tested in a child process."""
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE],
            capture_output=True,
            timeout=timeout_s,
            env=dict(os.environ),
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return proc.returncode == 0


def _fall_back(mi: types.ModuleType, reason: str) -> str:
    msg = (
        f"Mitsuba variant {PREFERRED_VARIANT!r} is unavailable ({reason}); falling back to "
        f"{FALLBACK_VARIANT!r}, which renders about 30x slower. Install Debian's libllvm19 "
        f"(`make setup` does) or set DRJIT_LIBLLVM_PATH to a libLLVM >= 15 that works."
    )
    log.warning(msg)
    warnings.warn(msg, RuntimeWarning, stacklevel=3)
    mi.set_variant(FALLBACK_VARIANT)
    return FALLBACK_VARIANT


def configure(choice: str, libllvm_path: str | None = None) -> None:
    """Set this process's variant choice (``auto`` or a name in :data:`VARIANT_CHOICES`)
    for later :func:`load_mitsuba` calls without an explicit variant. Called once at start-up
    by the edge (worker, ``matforge run``, a shard process's initialiser); cheap: Mitsuba is
    imported by the first :func:`load_mitsuba`. A choice other than the one already resolved
    in this process switches Mitsuba's global variant on that next call."""
    global _choice, _libllvm, _settled
    if choice not in VARIANT_CHOICES:
        raise ValueError(
            f"unknown Mitsuba variant {choice!r}; choose one of {', '.join(VARIANT_CHOICES)}"
        )
    with _lock:
        if choice != _choice:
            _choice, _settled = choice, False
        if libllvm_path:
            _libllvm = libllvm_path


def configured_choice() -> str:
    """The choice set by :func:`configure` (``"auto"`` unless configured)."""
    return _choice


def cuda_available(dr: types.ModuleType) -> bool:
    """Whether Dr.Jit's CUDA backend starts here (a driver and a device)."""
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # a broken driver reads as no CUDA, never as a crash of the loader
        return False


def _require(mi: types.ModuleType, dr: types.ModuleType, variant: str) -> None:
    """Raise :class:`VariantUnavailable` unless ``variant`` can run in this process."""
    if variant not in mi.variants():
        raise VariantUnavailable(
            f"Mitsuba variant {variant!r} is not built into this Mitsuba "
            f"({mi.__version__}); available: {', '.join(mi.variants())}"
        )
    if variant.startswith("cuda") and not cuda_available(dr):
        raise VariantUnavailable(
            f"Mitsuba variant {variant!r} needs CUDA, but Dr.Jit finds no CUDA driver and "
            f"device on this machine; use 'llvm_ad_rgb' (the CPU) or 'auto'"
        )
    if variant.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        raise VariantUnavailable(
            f"Mitsuba variant {variant!r} needs a libLLVM >= 15 that works, and Dr.Jit "
            f"found none; install Debian's libllvm19 (`make setup` does) or set "
            f"DRJIT_LIBLLVM_PATH"
        )


def load_mitsuba(variant: str | None = None, libllvm_path: str | None = None) -> types.ModuleType:
    """Import Mitsuba 3 with a variant set, and return the ``mitsuba`` module.

    Parameters
    ----------
    variant
        ``None`` (the default) resolves the process's choice (:func:`configure`; ``auto``
        unless configured): ``auto`` picks :data:`CUDA_VARIANT` where Dr.Jit finds CUDA,
        else :data:`PREFERRED_VARIANT` (``"llvm_ad_rgb"``), falling back to
        :data:`FALLBACK_VARIANT` (``"scalar_rgb"``) with a warning when the LLVM backend
        cannot start. An explicit name (as argument or as the configured choice) sets
        exactly that variant and raises :class:`VariantUnavailable` (an ``ImportError``)
        if it cannot run here.
    libllvm_path
        The libLLVM that Dr.Jit should use, exported as ``DRJIT_LIBLLVM_PATH`` before the
        first import unless that variable is already set or the file does not exist
        (default: the configured path, else :data:`DEFAULT_LIBLLVM`).

    The result is cached: later calls with ``variant=None`` return the same module with the
    variant resolved first (unless :func:`configure` changed the choice); an explicit
    different variant switches Mitsuba's global variant. Thread-safe.
    """
    global _module, _variant, _settled
    with _lock:
        wanted = variant if variant is not None else _choice
        if _module is not None and (wanted == _variant or (variant is None and _settled)):
            return _module
        _point_drjit_at_libllvm(libllvm_path or _libllvm or DEFAULT_LIBLLVM)
        explicit_path = os.environ.get("DRJIT_LIBLLVM_PATH")
        import drjit as dr
        import mitsuba as mi

        if wanted != "auto":
            _require(mi, dr, wanted)
            if wanted.startswith("llvm") and explicit_path is None and not _llvm_probe_ok():
                raise VariantUnavailable(
                    f"Mitsuba variant {wanted!r}: the libLLVM that Dr.Jit found fails to "
                    f"compile kernels; install Debian's libllvm19 or set DRJIT_LIBLLVM_PATH"
                )
            mi.set_variant(wanted)
            chosen = wanted
        elif CUDA_VARIANT in mi.variants() and cuda_available(dr):
            mi.set_variant(CUDA_VARIANT)
            chosen = CUDA_VARIANT
        elif PREFERRED_VARIANT not in mi.variants():
            chosen = _fall_back(mi, "not built into this Mitsuba")
        elif not dr.has_backend(dr.JitBackend.LLVM):
            chosen = _fall_back(mi, "Dr.Jit found no usable libLLVM")
        elif explicit_path is None and not _llvm_probe_ok():
            # Dr.Jit picked a libLLVM by itself; on Debian that may be LLVM 15, which
            # aborts the process on the first kernel. The probe ran it in a child process.
            chosen = _fall_back(mi, "the libLLVM that Dr.Jit found fails to compile kernels")
        else:
            try:
                mi.set_variant(PREFERRED_VARIANT)
                chosen = PREFERRED_VARIANT
            except (ImportError, RuntimeError) as exc:
                chosen = _fall_back(mi, str(exc).splitlines()[0] if str(exc) else "error")
        _module, _variant, _settled = mi, chosen, True
        log.info("Mitsuba %s ready with variant %s", mi.__version__, chosen)
        return mi


def active_variant() -> str | None:
    """The variant set by :func:`load_mitsuba`, or ``None`` if Mitsuba is not loaded yet."""
    return _variant


def runs_on_cpu_jit(mi: types.ModuleType) -> bool:
    """Whether the active variant JIT-compiles for the CPU (an ``llvm_`` variant): there a
    timing's clock is the process's CPU time over its threads, not the wall clock."""
    return str(mi.variant()).startswith("llvm_")


def jit_backend(mi: types.ModuleType | None = None) -> types.ModuleType:
    """The Dr.Jit array module of the active variant's backend (``drjit.llvm`` or
    ``drjit.cuda``; their ``ad`` flavours are what ``mi.Float`` is), for the types Mitsuba
    does not re-export (``Float64``, ``UInt64``). Loads Mitsuba if needed; raises
    ``RuntimeError`` under a scalar variant, which has no JIT arrays."""
    mi = mi or load_mitsuba()
    variant = mi.variant() or ""
    if variant.startswith(("cuda", "llvm")):
        # The one place a backend module is named (tests/unit/evaluators/render/
        # test_variant_generic.py keeps it so).
        return importlib.import_module("drjit.cuda" if variant.startswith("cuda") else "drjit.llvm")
    raise RuntimeError(
        f"Mitsuba variant {variant!r} has no Dr.Jit JIT backend; this needs a vectorised "
        f"variant (llvm_ad_rgb or cuda_ad_rgb)"
    )
