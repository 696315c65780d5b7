"""The one place where matforge imports Mitsuba 3 (and with it Dr.Jit) and picks its variant.

Every module that needs Mitsuba or a Dr.Jit array type calls :func:`load_mitsuba` and uses
the module it returns; nothing else calls ``mitsuba.set_variant``. It lives in
``materials`` because the Dr.Jit twins of the physics need a JIT backend as much as the
renderer does; Mitsuba *plugins* (BSDFs, integrators) live in :mod:`evaluators.render`.

Why a loader at all: the fast CPU variant, ``llvm_ad_rgb``, JIT-compiles kernels through a
shared libLLVM that Dr.Jit finds at run time. On the Debian machines matforge targets, the
system's default libLLVM-15 aborts the whole process while compiling (``LLVM ERROR: Cannot
select ... fminimum``), so Dr.Jit has to be pointed at libLLVM-19 *before* ``mitsuba`` is
imported. Where no usable libLLVM exists, the loader falls back to ``scalar_rgb`` (about 30x
slower) and says so loudly; the variant in use is written into every render's metadata.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import types
import warnings
from pathlib import Path

log = logging.getLogger(__name__)

#: The variant used for all real work: vectorised CPU rendering through LLVM.
PREFERRED_VARIANT = "llvm_ad_rgb"
#: The variant used when the LLVM backend cannot start (no libLLVM, or a broken one).
FALLBACK_VARIANT = "scalar_rgb"
#: Debian's libLLVM-19 (``apt-get install libllvm19``), installed by ``make setup``.
DEFAULT_LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"

_lock = threading.RLock()
_module: types.ModuleType | None = None
_variant: str | None = None

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


def load_mitsuba(
    variant: str | None = None, libllvm_path: str = DEFAULT_LIBLLVM
) -> types.ModuleType:
    """Import Mitsuba 3 with a variant set, and return the ``mitsuba`` module.

    Parameters
    ----------
    variant
        ``None`` (the default) picks :data:`PREFERRED_VARIANT` (``"llvm_ad_rgb"``) and falls
        back to :data:`FALLBACK_VARIANT` (``"scalar_rgb"``) with a warning when the LLVM
        backend cannot start. An explicit name sets exactly that variant and raises
        ``ImportError`` if Mitsuba cannot provide it.
    libllvm_path
        The libLLVM that Dr.Jit should use, exported as ``DRJIT_LIBLLVM_PATH`` before the
        first import unless that variable is already set or the file does not exist.

    The result is cached: later calls with ``variant=None`` return the same module with the
    variant chosen first; an explicit different variant switches Mitsuba's global variant.
    Thread-safe.
    """
    global _module, _variant
    with _lock:
        if _module is not None and (variant is None or variant == _variant):
            return _module
        _point_drjit_at_libllvm(libllvm_path)
        explicit_path = os.environ.get("DRJIT_LIBLLVM_PATH")
        import drjit as dr
        import mitsuba as mi

        if variant is not None:
            if variant not in mi.variants():
                raise ImportError(
                    f"Mitsuba variant {variant!r} is not available; "
                    f"available: {', '.join(mi.variants())}"
                )
            mi.set_variant(variant)
            chosen = variant
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
        _module, _variant = mi, chosen
        log.info("Mitsuba %s ready with variant %s", mi.__version__, chosen)
        return mi


def active_variant() -> str | None:
    """The variant set by :func:`load_mitsuba`, or ``None`` if Mitsuba is not loaded yet."""
    return _variant
