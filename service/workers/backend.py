"""The Mitsuba variant at the edge: resolved at start-up, handed to every process that runs
a job's code, refused clearly when it cannot run.

``MATFORGE_VARIANT`` (:attr:`service.settings.Settings.variant`) is a *choice*: ``auto`` or
a variant's name. The processes that run kinds' code resolve it once, when they start:

- a worker and ``matforge run`` call :func:`start_backend` before claiming a job (it
  configures :mod:`materials.backend` and imports Mitsuba with the variant);
- their shard processes (the local pool, Ray tasks) run :func:`setup_shard_process` with
  the variant the job's process resolved, so a job's shards never disagree with it;
- ``matforge serve`` calls :func:`probe_variant`, which resolves the choice in a child
  process (the web process never imports Mitsuba) and refuses to start on an error; the
  resolved name is what its workers get, and what the submissions' identity uses
  (:func:`identity_variant`).

This is the one module of ``service`` that imports :mod:`materials` (an import contract
names the exception): picking the renderer's backend is the edge's business, by the rule
"the environment is read in one settings module and passed down".
"""

from __future__ import annotations

import functools
import subprocess
import sys

import materials.backend as backend
from jobapi.errors import BackendUnavailable
from service.settings import Settings

#: Seconds the start-up probe of ``matforge serve`` may take (an LLVM probe included).
PROBE_SECONDS = 180.0


def _refusal(choice: str, reason: str) -> BackendUnavailable:
    return BackendUnavailable(
        f"MATFORGE_VARIANT={choice}: {reason} (MATFORGE_VARIANT takes auto, "
        f"{', '.join(v for v in backend.VARIANT_CHOICES if v != 'auto')})"
    )


def start_backend(settings: Settings) -> str:
    """Configure this process's Mitsuba variant from ``settings`` and load it; returns the
    variant in use. Raises :class:`~jobapi.errors.BackendUnavailable` naming
    ``MATFORGE_VARIANT`` when it cannot run here."""
    backend.configure(settings.variant, settings.libllvm_path)
    try:
        mi = backend.load_mitsuba()
    except ImportError as exc:  # VariantUnavailable, or a Mitsuba that does not import
        raise _refusal(settings.variant, str(exc)) from None
    return str(mi.variant())


def setup_shard_process(variant: str, libllvm_path: str) -> None:
    """A shard process's initialiser: the variant its job's process resolved (cheap;
    Mitsuba is imported by the first shard that needs it). Module-level, so picklable."""
    backend.configure(variant, libllvm_path)


def probe_variant(settings: Settings, timeout_s: float = PROBE_SECONDS) -> str:
    """Resolve ``settings.variant`` in a child process, exactly as a worker would; returns
    the variant's name, or raises :class:`~jobapi.errors.BackendUnavailable`."""
    cmd = [sys.executable, "-m", "service.workers.backend"]
    try:
        proc = subprocess.run(
            cmd,
            env=settings.to_env() | _inherited(),
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
    except subprocess.TimeoutExpired:
        raise _refusal(settings.variant, f"loading Mitsuba took over {timeout_s:g} s") from None
    lines = (proc.stdout or "").strip().splitlines()
    if proc.returncode == 0 and lines:
        return lines[-1].strip()
    why = (proc.stderr or "").strip().splitlines()
    raise BackendUnavailable(why[-1] if why else f"the variant probe exited {proc.returncode}")


def _inherited() -> dict[str, str]:
    # The child needs the interpreter's own environment (PATH, HOME, a venv's variables)
    # beside the settings; ``to_env`` carries only matforge's.
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("MATFORGE_")}


@functools.lru_cache(maxsize=8)
def _resolved(choice: str, libllvm_path: str) -> str:
    # Only what decides the variant is the key: a test's app per data directory probes once.
    return probe_variant(Settings(variant=choice, libllvm_path=libllvm_path))


def identity_variant(settings: Settings) -> str:
    """The variant a submission's identity uses: the setting's name, or for ``auto`` the
    one the workers of this machine will resolve (probed once per process and cached)."""
    if settings.variant != "auto":
        return settings.variant
    return _resolved(settings.variant, settings.libllvm_path)


def main() -> int:
    """``python -m service.workers.backend``: print the variant the environment's settings
    resolve to, or the refusal on stderr (exit 2)."""
    try:
        print(start_backend(Settings.from_env()))
    except (BackendUnavailable, ValueError) as exc:
        print(str(exc), file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
