"""The one place matforge reads its environment.

Every other module receives a :class:`Settings` (or plain values taken from it); nothing
deeper in the code reads ``os.environ``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

DEFAULT_SERVER = "http://127.0.0.1:8000"
DEFAULT_LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
#: The shard backends ``MATFORGE_EXECUTOR`` may name; the first is the default.
EXECUTORS: tuple[str, ...] = ("process", "ray")
#: The Mitsuba variants ``MATFORGE_VARIANT`` may name; the first is the default. The same
#: tuple as :data:`materials.backend.VARIANT_CHOICES` (a test keeps them equal).
VARIANTS: tuple[str, ...] = ("auto", "llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb")


def _int(env: dict[str, str], name: str, default: int) -> int:
    raw = env.get(name)
    if raw is None or raw == "":
        return default
    try:
        return int(raw)
    except ValueError as exc:
        raise ValueError(f"environment variable {name}={raw!r} is not an integer") from exc


def _float(env: dict[str, str], name: str, default: float) -> float:
    raw = env.get(name)
    if raw is None or raw == "":
        return default
    try:
        return float(raw)
    except ValueError as exc:
        raise ValueError(f"environment variable {name}={raw!r} is not a number") from exc


#: The least memory a job's process gets when the limit is shared out automatically.
JOB_MEMORY_FLOOR = 1 << 30


def physical_memory() -> int | None:
    """This machine's memory in bytes (``None`` where the OS does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def _memory_mb(env: dict[str, str], name: str) -> int | None:
    """``None`` for unset or ``auto``, else the MiB given as bytes (0: no limit)."""
    raw = (env.get(name) or "").strip().lower()
    if raw in ("", "auto"):
        return None
    try:
        mb = int(raw)
    except ValueError:
        raise ValueError(
            f"environment variable {name}={raw!r} is not a number of MiB (or auto)"
        ) from None
    if mb < 0:
        raise ValueError(f"environment variable {name}={raw!r} must be 0 (no limit) or more")
    return mb << 20


def _flag(env: dict[str, str], name: str) -> bool:
    raw = (env.get(name) or "").strip().lower()
    if raw in ("", "0", "false", "no", "off"):
        return False
    if raw in ("1", "true", "yes", "on"):
        return True
    raise ValueError(f"environment variable {name}={raw!r} is not a flag (1 or 0)")


def _choice(env: dict[str, str], name: str, choices: tuple[str, ...]) -> str:
    raw = (env.get(name) or choices[0]).strip().lower()
    if raw not in choices:
        raise ValueError(f"environment variable {name}={raw!r} is not one of {', '.join(choices)}")
    return raw


@dataclass(frozen=True)
class Settings:
    """Service and client configuration.

    Environment variables (all optional):

    ============================  ===========================  ==============================
    variable                      field                        default
    ============================  ===========================  ==============================
    ``MATFORGE_DATA``             ``data_dir``                 ``./matforge-data``
    ``MATFORGE_SERVER``           ``server``                   ``http://127.0.0.1:8000``
    ``MATFORGE_TOKEN``            ``token``                    unset (no auth)
    ``MATFORGE_LEASE_SECONDS``    ``lease_seconds``            30
    ``MATFORGE_MAX_ATTEMPTS``     ``max_attempts``             3
    ``MATFORGE_WORKERS``          ``workers``                  1
    ``MATFORGE_RECYCLE_JOBS``     ``recycle_after_jobs``       20
    ``MATFORGE_MAX_UPLOAD_MB``    ``max_upload_bytes``         512 MiB
    ``MATFORGE_MAX_BODY_KB``      ``max_body_bytes``           1 MiB (JSON bodies)
    ``MATFORGE_UPLOAD_CHECK_MB``  ``upload_check_bytes``       2 GiB (memory to validate one)
    ``MATFORGE_ARCHIVE_MPIX``     ``archive_max_pixels``       64 Mpix (an archive's images)
    ``MATFORGE_JOB_MEMORY_MB``    ``job_memory_bytes``         auto: a share of RAM (below)
    ``MATFORGE_ALLOWED_HOSTS``    ``allowed_hosts``            the bound host (and loopback)
    ``MATFORGE_POOL_PROCESSES``   ``pool_processes``           cores, at most 2
    ``MATFORGE_STALL_SECONDS``    ``stall_seconds``            unset: each kind's own
    ``MATFORGE_GC_GRACE_HOURS``   ``gc_grace_seconds``         24 h
    ``MATFORGE_EXECUTOR``         ``executor``                 ``process`` (or ``ray``)
    ``RAY_ADDRESS``               ``ray_address``              unset: a private local Ray
    ``MATFORGE_RAY_MAX_RETRIES``  ``ray_max_retries``          3 (per shard)
    ``RAY_AUTH_MODE``             ``ray_auth_mode``            unset (Ray's own default)
    ``MATFORGE_SHARED_STORE``     ``shared_store``             0 (shards' bytes come back)
    ``DRJIT_LIBLLVM_PATH``        ``libllvm_path``             Debian's libLLVM-19
    ``MATFORGE_VARIANT``          ``variant``                  ``auto`` (cuda, else llvm)
    ============================  ===========================  ==============================

    ``variant`` is the Mitsuba variant every job renders and evaluates with
    (:data:`VARIANTS`): ``auto`` takes ``cuda_ad_rgb`` where Dr.Jit finds a CUDA device and
    ``llvm_ad_rgb`` otherwise (``scalar_rgb``, loudly, where no libLLVM works); a name
    takes exactly that variant, and a worker, ``matforge run`` or ``matforge serve`` refuses
    to start when it cannot run (:mod:`service.workers.backend`). The variant in use is in
    every job's manifest, and part of a spec's identity for the kinds whose bytes depend on
    it (:attr:`jobapi.kinds.Kind.variant_bytes`).

    Uploads are checked, and EXR previews made, in a pool of bounded child processes
    (:mod:`service.upload_check`):

    ==================================  =========================  =================================
    variable                            field                      default
    ==================================  =========================  =================================
    ``MATFORGE_UPLOAD_CHECKERS``        ``upload_checkers``        2 (files checked at once)
    ``MATFORGE_UPLOAD_CHECK_SECONDS``   ``upload_check_seconds``   120 (the most one check may take)
    ``MATFORGE_UPLOAD_QUEUE_SECONDS``   ``upload_queue_seconds``   10 (wait for a checker; 503)
    ``MATFORGE_UPLOAD_BUDGET_SECONDS``  ``upload_budget_seconds``  10 (plus 1 s per MiB; 413)
    ``MATFORGE_UPLOAD_INFLATE_RATIO``   ``upload_inflate_ratio``   20 (x the upload + 16 MiB; 413)
    ``MATFORGE_PREVIEW_MAX_PIXELS``     ``preview_max_pixels``     2**24 (largest EXR previewed)
    ==================================  =========================  =================================

    Each upload has a **budget** (:meth:`service.upload_check.UploadChecker.budget_for`):
    its check may take ``upload_budget_seconds`` plus one
    second per MiB uploaded (at most ``upload_check_seconds``), and the members of an
    archive (``.btf.zip``, ``.npz``) may inflate to ``upload_inflate_ratio`` times the
    upload's size plus 16 MiB, summed from the zip directory before anything is inflated.
    Past either, the upload is refused with 413, the error naming what was over.

    ``job_memory_bytes`` caps the memory of every process that runs a job's code in
    ``matforge serve`` (a worker and each of its shard processes), enforced by the kernel
    (``RLIMIT_DATA``: heap and private writable mappings, not reserved address space, which
    Dr.Jit's LLVM JIT, torch and onnxruntime reserve far beyond their use). A job past it
    fails with an error that starts ``out of memory`` and its worker is replaced
    (:mod:`service.workers.memory`). Unset or ``auto``: :meth:`job_memory_limit` shares
    three quarters of the machine's memory among the workers and their shard processes, at
    least 1 GiB each; ``0``: no limit.

    ``stall_seconds``, when set, replaces every kind's stall limit
    (:attr:`jobapi.kinds.Kind.stall_seconds`): a running job that reports no progress for
    that long fails as stuck (:class:`service.workers.execution.Heartbeat`).

    ``executor`` picks the backend of the jobs' shards (:mod:`service.workers.executors`):
    ``process`` is a pool of ``pool_processes`` local processes; ``ray`` sends shards to the
    Ray cluster at ``ray_address`` (``host:port`` of its head), or to a private local Ray of
    ``pool_processes`` CPUs when unset. Ray reads ``RAY_AUTH_MODE`` and ``RAY_AUTH_TOKEN`` /
    ``RAY_AUTH_TOKEN_PATH`` itself; matforge reads the mode only to warn when it connects
    to a cluster without token authentication.

    ``shared_store`` (``MATFORGE_SHARED_STORE=1``) says that every process running shards
    sees the data directory's store at the same absolute path: one machine, or a POSIX file
    system that every node mounts (NFS, Lustre). Then each shard task writes its own bytes
    into the store, with the store's atomic temp-file, fsync, rename protocol, and returns
    only their digest and size; the job's thread checks size and records digests
    (:meth:`jobapi.context.JobContext.map_artifact_shards`). Unset, a shard's bytes travel
    back to the job, which stores them. It is an operator's statement, never guessed from
    the file system: a store that is not in fact shared fails the job, naming the path.
    """

    data_dir: Path = Path("./matforge-data")
    server: str = DEFAULT_SERVER
    token: str | None = None
    lease_seconds: float = 30.0
    max_attempts: int = 3
    workers: int = 1
    recycle_after_jobs: int = 20
    max_upload_bytes: int = 512 * 1024 * 1024
    max_body_bytes: int = 1024 * 1024
    upload_check_bytes: int = 2048 * 1024 * 1024
    upload_checkers: int = 2
    upload_check_seconds: float = 120.0
    upload_queue_seconds: float = 10.0
    preview_max_pixels: int = 1 << 24
    archive_max_pixels: int = 64 * 1000 * 1000
    upload_budget_seconds: float = 10.0
    upload_inflate_ratio: float = 20.0
    #: ``None``: a share of the machine's memory (:meth:`job_memory_limit`); 0: no limit.
    job_memory_bytes: int | None = None
    allowed_hosts: tuple[str, ...] = ()
    pool_processes: int = 2
    stall_seconds: float | None = None
    gc_grace_seconds: float = 24 * 3600.0
    libllvm_path: str = DEFAULT_LIBLLVM
    executor: str = "process"
    ray_address: str | None = None
    ray_max_retries: int = 3
    ray_auth_mode: str | None = None
    shared_store: bool = False
    variant: str = "auto"
    extra: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None) -> Settings:
        """Build settings from ``env`` (default: the process environment)."""
        e = dict(os.environ if env is None else env)
        token = e.get("MATFORGE_TOKEN") or None
        return cls(
            data_dir=Path(e.get("MATFORGE_DATA") or "./matforge-data"),
            server=(e.get("MATFORGE_SERVER") or DEFAULT_SERVER).rstrip("/"),
            token=token,
            lease_seconds=_float(e, "MATFORGE_LEASE_SECONDS", 30.0),
            max_attempts=_int(e, "MATFORGE_MAX_ATTEMPTS", 3),
            workers=_int(e, "MATFORGE_WORKERS", 1),
            recycle_after_jobs=_int(e, "MATFORGE_RECYCLE_JOBS", 20),
            max_upload_bytes=_int(e, "MATFORGE_MAX_UPLOAD_MB", 512) * 1024 * 1024,
            max_body_bytes=_int(e, "MATFORGE_MAX_BODY_KB", 1024) * 1024,
            upload_check_bytes=_int(e, "MATFORGE_UPLOAD_CHECK_MB", 2048) * 1024 * 1024,
            upload_checkers=max(1, _int(e, "MATFORGE_UPLOAD_CHECKERS", 2)),
            upload_check_seconds=_float(e, "MATFORGE_UPLOAD_CHECK_SECONDS", 120.0),
            upload_queue_seconds=_float(e, "MATFORGE_UPLOAD_QUEUE_SECONDS", 10.0),
            preview_max_pixels=_int(e, "MATFORGE_PREVIEW_MAX_PIXELS", 1 << 24),
            archive_max_pixels=int(_float(e, "MATFORGE_ARCHIVE_MPIX", 64.0) * 1e6),
            upload_budget_seconds=_float(e, "MATFORGE_UPLOAD_BUDGET_SECONDS", 10.0),
            upload_inflate_ratio=_float(e, "MATFORGE_UPLOAD_INFLATE_RATIO", 20.0),
            job_memory_bytes=_memory_mb(e, "MATFORGE_JOB_MEMORY_MB"),
            allowed_hosts=tuple(
                h.strip().lower()
                for h in (e.get("MATFORGE_ALLOWED_HOSTS") or "").split(",")
                if h.strip()
            ),
            pool_processes=max(1, _int(e, "MATFORGE_POOL_PROCESSES", min(2, os.cpu_count() or 1))),
            stall_seconds=_float(e, "MATFORGE_STALL_SECONDS", 0.0) or None,
            gc_grace_seconds=_float(e, "MATFORGE_GC_GRACE_HOURS", 24.0) * 3600.0,
            libllvm_path=e.get("DRJIT_LIBLLVM_PATH") or DEFAULT_LIBLLVM,
            executor=_choice(e, "MATFORGE_EXECUTOR", EXECUTORS),
            ray_address=e.get("RAY_ADDRESS") or None,
            ray_max_retries=max(0, _int(e, "MATFORGE_RAY_MAX_RETRIES", 3)),
            ray_auth_mode=e.get("RAY_AUTH_MODE") or None,
            shared_store=_flag(e, "MATFORGE_SHARED_STORE"),
            variant=_choice(e, "MATFORGE_VARIANT", VARIANTS),
        )

    def to_env(self) -> dict[str, str]:
        """The environment variables that reproduce these settings in a child process."""
        env = {
            "MATFORGE_DATA": str(self.data_dir),
            "MATFORGE_SERVER": self.server,
            "MATFORGE_LEASE_SECONDS": repr(self.lease_seconds),
            "MATFORGE_MAX_ATTEMPTS": str(self.max_attempts),
            "MATFORGE_WORKERS": str(self.workers),
            "MATFORGE_RECYCLE_JOBS": str(self.recycle_after_jobs),
            "MATFORGE_MAX_UPLOAD_MB": str(self.max_upload_bytes // (1024 * 1024)),
            "MATFORGE_MAX_BODY_KB": str(self.max_body_bytes // 1024),
            "MATFORGE_UPLOAD_CHECK_MB": str(self.upload_check_bytes // (1024 * 1024)),
            "MATFORGE_UPLOAD_CHECKERS": str(self.upload_checkers),
            "MATFORGE_UPLOAD_CHECK_SECONDS": repr(self.upload_check_seconds),
            "MATFORGE_UPLOAD_QUEUE_SECONDS": repr(self.upload_queue_seconds),
            "MATFORGE_PREVIEW_MAX_PIXELS": str(self.preview_max_pixels),
            "MATFORGE_ARCHIVE_MPIX": repr(self.archive_max_pixels / 1e6),
            "MATFORGE_UPLOAD_BUDGET_SECONDS": repr(self.upload_budget_seconds),
            "MATFORGE_UPLOAD_INFLATE_RATIO": repr(self.upload_inflate_ratio),
            "MATFORGE_JOB_MEMORY_MB": (
                "auto" if self.job_memory_bytes is None else str(self.job_memory_bytes >> 20)
            ),
            "MATFORGE_ALLOWED_HOSTS": ",".join(self.allowed_hosts),
            "MATFORGE_POOL_PROCESSES": str(self.pool_processes),
            "MATFORGE_GC_GRACE_HOURS": repr(self.gc_grace_seconds / 3600.0),
            "DRJIT_LIBLLVM_PATH": self.libllvm_path,
            "MATFORGE_EXECUTOR": self.executor,
            "MATFORGE_RAY_MAX_RETRIES": str(self.ray_max_retries),
            "MATFORGE_SHARED_STORE": "1" if self.shared_store else "0",
            "MATFORGE_VARIANT": self.variant,
        }
        if self.stall_seconds:
            env["MATFORGE_STALL_SECONDS"] = repr(self.stall_seconds)
        if self.ray_address:
            env["RAY_ADDRESS"] = self.ray_address
        if self.ray_auth_mode:
            env["RAY_AUTH_MODE"] = self.ray_auth_mode
        if self.token:
            env["MATFORGE_TOKEN"] = self.token
        return env

    def with_(self, **changes: object) -> Settings:
        """A copy with some fields replaced (settings are immutable)."""
        return replace(self, **changes)  # type: ignore[arg-type]

    def job_memory_limit(self) -> int | None:
        """Bytes each process running a job's code may use (``RLIMIT_DATA``), or ``None``
        for no limit. ``auto``: three quarters of this machine's memory shared among
        ``workers`` workers, each with ``pool_processes`` shard processes, at least 1 GiB."""
        if self.job_memory_bytes is not None:
            return self.job_memory_bytes or None
        total = physical_memory()
        if total is None:
            return None
        share = (3 * total // 4) // (max(1, self.workers) * (1 + max(1, self.pool_processes)))
        return max(JOB_MEMORY_FLOOR, share)

    @property
    def db_path(self) -> Path:
        return self.data_dir / "jobs.sqlite3"

    @property
    def store_dir(self) -> Path:
        return self.data_dir / "store"
