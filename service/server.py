"""``matforge serve``: the web app in this process, the jobs in N worker processes.

:func:`serve` starts a :class:`service.workers.worker.Supervisor` (which keeps ``workers`` worker
processes alive and re-queues the jobs of dead ones), then runs uvicorn with
:func:`service.api.create_app`. On SIGINT or SIGTERM uvicorn shuts down gracefully and the
supervisor stops its workers (SIGTERM, then SIGKILL after a grace period) before this
function returns. Heavy work never runs in the web process.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import socket
import sys
import threading
from types import FrameType

import uvicorn

from service.api import create_app
from service.settings import Settings
from service.web_guard import RedactTokens
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


def serve(settings: Settings, host: str = "127.0.0.1", port: int = 8000, workers: int = 1) -> None:
    """Run the API and dashboard on ``host:port`` with ``workers`` worker processes over
    ``settings.data_dir`` until SIGINT or SIGTERM. Logs (level info) go to stderr.

    ``port=0`` picks a free port; the line ``matforge dashboard: <url>`` on stderr names it.
    """
    if not logging.getLogger().handlers:
        logging.basicConfig(
            level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(name)s %(message)s"
        )
    (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)  # workers' job dirs
    app = create_app(settings, bind_host=host)
    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="info",
        timeout_graceful_shutdown=5,
        server_header=False,
    )
    # After Config, which (re)configures uvicorn's loggers: ?token= never reaches the log.
    logging.getLogger("uvicorn.access").addFilter(RedactTokens())
    supervisor = Supervisor(settings, workers)
    server = _Server(config, supervisor, token=bool(settings.token))
    # uvicorn re-raises the signal that stopped it once it has shut down; a SIGTERM then
    # ends the process through SystemExit (so ``finally`` blocks run), not abruptly.
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm) if main else None
    supervisor.start()
    log.info("started %d worker process(es) over %s", workers, settings.data_dir)
    try:
        server.run()
    except KeyboardInterrupt:
        pass
    except SystemExit as exc:
        if exc.code not in (0, None):  # e.g. uvicorn could not bind the port
            raise
    finally:
        supervisor.stop()
        if main:
            signal.signal(signal.SIGTERM, previous)
