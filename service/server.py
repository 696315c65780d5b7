"""``matforge serve``: the web app in this process, the jobs in N worker processes.

:func:`serve` starts a :class:`service.workers.worker.Supervisor` (which keeps ``workers`` worker
processes alive and re-queues the jobs of dead ones), then runs uvicorn with
:func:`service.api.create_app`. On SIGINT or SIGTERM uvicorn shuts down gracefully and the
supervisor stops its workers (SIGTERM, then SIGKILL after a grace period) before this
function returns. Heavy work never runs in the web process.

With ``http_workers`` > 1 the web app runs in that many processes on one listening socket,
bound here and inherited by the others (spawned, each with its own app, store connections
and event loop; the kernel spreads the connections over them). The job store's writers of
all of them queue on one lock (:mod:`storage.write_lock`). The extra web processes watch
this one and exit when it is gone, like the job workers do.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import signal
import socket
import sys
import threading
from types import FrameType

import uvicorn

from service.api import create_app
from service.settings import Settings
from service.web_guard import RedactTokens, bind_refusal, is_loopback
from service.workers.backend import probe_variant
from service.workers.liveness import watch_parent
from service.workers.worker import Supervisor

log = logging.getLogger("matforge.server")


def _display_url(server: uvicorn.Server, host: str, port: int) -> str:
    """The URL to open: the real port (``port=0`` picks one) and a loopback address for a
    wildcard host."""
    for srv in getattr(server, "servers", []):
        for sock in srv.sockets or ():
            if sock.family in (socket.AF_INET, socket.AF_INET6):
                port = sock.getsockname()[1]
                break
    shown = {"0.0.0.0": "127.0.0.1", "": "127.0.0.1", "::": "[::1]"}.get(host, host)
    if ":" in shown and not shown.startswith("["):
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/"


class _Server(uvicorn.Server):
    """uvicorn's server, which announces the dashboard URL once it listens and stops the
    workers as part of its graceful shutdown."""

    def __init__(self, config: uvicorn.Config, supervisor: Supervisor, token: bool) -> None:
        super().__init__(config)
        self.supervisor = supervisor
        self.token = token

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=sockets)
        if not self.should_exit:
            url = _display_url(self, self.config.host, self.config.port)
            hint = "  (needs the token: open it as /?token=<MATFORGE_TOKEN>)" if self.token else ""
            print(f"matforge dashboard: {url}{hint}", file=sys.stderr, flush=True)

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        await super().shutdown(sockets=sockets)
        await asyncio.to_thread(self.supervisor.stop)


def _exit_on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(0)


def _config(settings: Settings, host: str, port: int) -> uvicorn.Config:
    if not logging.getLogger().handlers:
        logging.basicConfig(
            level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(name)s %(message)s"
        )
    config = uvicorn.Config(
        create_app(settings, bind_host=host),
        host=host,
        port=port,
        log_level="info",
        timeout_graceful_shutdown=5,
        server_header=False,
    )
    # After Config, which (re)configures uvicorn's loggers: ?token= never reaches the log.
    logging.getLogger("uvicorn.access").addFilter(RedactTokens())
    return config


def _http_process(
    settings: Settings, host: str, port: int, sock: socket.socket, parent_pid: int
) -> None:
    """One extra web process (spawned): serve the app on the parent's socket until told to
    stop, or until the parent is gone."""
    watch_parent(parent_pid)
    uvicorn.Server(_config(settings, host, port)).run(sockets=[sock])


def _stop(procs: list[mp.process.BaseProcess], grace_s: float = 5.0) -> None:
    for p in procs:
        if p.is_alive():
            p.terminate()  # SIGTERM: uvicorn's graceful shutdown
    for p in procs:
        p.join(grace_s)
        if p.is_alive():
            p.kill()
            p.join()


def serve(
    settings: Settings,
    host: str = "127.0.0.1",
    port: int = 8000,
    workers: int = 1,
    http_workers: int = 1,
) -> None:
    """Run the API and dashboard on ``host:port`` in ``http_workers`` web processes, with
    ``workers`` job worker processes over ``settings.data_dir``, until SIGINT or SIGTERM.
    Logs (level info) go to stderr.

    ``port=0`` picks a free port; the line ``matforge dashboard: <url>`` on stderr names it.
    """
    if http_workers < 1:
        raise ValueError(f"http_workers must be at least 1, not {http_workers}")
    refusal = bind_refusal(host, settings.allowed_hosts)
    if refusal is not None:
        raise ValueError(refusal)  # the CLI exits 2 with it; nothing was started
    if not settings.token and not is_loopback(host):
        log.warning(
            "listening on %s with no MATFORGE_TOKEN: anyone who can reach this address can "
            "submit jobs and read every artifact",
            host or "every interface",
        )
    # MATFORGE_VARIANT, resolved as the workers will (in a child: the web process never
    # imports Mitsuba); BackendUnavailable, naming the setting, before anything starts. The
    # workers and the submissions' identity then use the resolved name.
    settings = settings.with_(variant=probe_variant(settings))
    log.info("Mitsuba variant: %s", settings.variant)
    (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)  # workers' job dirs
    config = _config(settings, host, port)
    sockets: list[socket.socket] | None = None
    extra: list[mp.process.BaseProcess] = []
    if http_workers > 1:
        sock = config.bind_socket()  # uvicorn: SO_REUSEADDR, inheritable
        sockets = [sock]
        ctx = mp.get_context("spawn")
        real_port = sock.getsockname()[1]
        for _ in range(http_workers - 1):
            p = ctx.Process(
                target=_http_process,
                args=(settings, host, real_port, sock, os.getpid()),
                name="matforge-http",
                daemon=True,
            )
            p.start()
            extra.append(p)
        log.info("started %d extra web process(es)", len(extra))
    supervisor = Supervisor(settings, workers)
    server = _Server(config, supervisor, token=bool(settings.token))
    # uvicorn re-raises the signal that stopped it once it has shut down; a SIGTERM then
    # ends the process through SystemExit (so ``finally`` blocks run), not abruptly.
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm) if main else None
    supervisor.start()
    log.info("started %d worker process(es) over %s", workers, settings.data_dir)
    try:
        server.run(sockets=sockets)
    except KeyboardInterrupt:
        pass
    except SystemExit as exc:
        if exc.code not in (0, None):  # e.g. uvicorn could not bind the port
            raise
    finally:
        _stop(extra)
        supervisor.stop()
        if main:
            signal.signal(signal.SIGTERM, previous)
