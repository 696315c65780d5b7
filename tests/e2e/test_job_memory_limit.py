"""Every job runs under a memory limit the kernel enforces (``MATFORGE_JOB_MEMORY_MB``).

A plugin kind (a hand-written ``.dist-info`` on the server's ``PYTHONPATH``, as in
``test_plugin_kinds``) asks for more than the limit, set low here (1536 MiB), in two ways:

- numpy asks for 8 GiB at once (``np.empty``: nothing is touched, so without a limit the
  allocation is granted and the job succeeds; under the limit it raises ``MemoryError``);
- Dr.Jit evaluates a 2 GiB array: under the limit its allocation fails and Dr.Jit ends the
  worker with SIGSEGV, so the supervisor has to name the job's failure.

Each fails with an error that starts ``out of memory``, its worker process is replaced, the
job is not retried, and the next job (a small render) succeeds on the same server;
``/api/health`` answers within 1 s after each.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from .harness import SMOKE_RENDER, Server, start_server, stop_server, worker_pids

pytestmark = pytest.mark.slow

LIMIT_MB = 1536
#: Seconds one job of this test may take on a shared 2-core machine (the render: a few s).
JOB_TIMEOUT_S = 120.0

ALLOC_KIND = """
from typing import Literal

from jobapi.kinds import Kind, register
from jobapi.params import StrictModel


class AllocParams(StrictModel):
    how: Literal["numpy", "drjit"]
    gib: float


def run(params, ctx):
    n = int(params.gib * 2**30)
    if params.how == "numpy":
        import numpy as np

        ctx.progress(0.5, f"numpy.empty of {n} bytes")
        block = np.empty(n, np.uint8)
        ctx.put_json("size.json", {"bytes": int(block.nbytes)})
    else:
        import drjit as dr
        import mitsuba as mi

        from materials.backend import load_mitsuba

        load_mitsuba()
        ctx.progress(0.5, f"Dr.Jit array of {n} bytes")
        x = dr.arange(mi.Float, n // 4) * 2.0
        dr.eval(x)
        ctx.put_json("size.json", {"bytes": n, "last": float(x[n // 4 - 1])})


register(
    Kind(name="test.alloc", params=AllocParams, runner=run,
         description="allocates what it is told (a memory-limit test)")
)
"""


def write_plugin(root: Path) -> Path:
    site = root / "site"
    info = site / "matforge_test_alloc-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: matforge-test-alloc\nVersion: 0.1\n"
    )
    (info / "entry_points.txt").write_text("[matforge.kinds]\nalloc = matforge_test_alloc\n")
    (site / "matforge_test_alloc.py").write_text(ALLOC_KIND)
    return site


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    root = tmp_path_factory.mktemp("job-memory")
    paths = [str(write_plugin(root))]
    if os.environ.get("PYTHONPATH"):
        paths.append(os.environ["PYTHONPATH"])
    srv = start_server(
        root,
        workers=1,
        extra_env={
            "PYTHONPATH": os.pathsep.join(paths),
            "MATFORGE_JOB_MEMORY_MB": str(LIMIT_MB),
            "MATFORGE_POOL_PROCESSES": "1",
        },
    )
    try:
        yield srv
    finally:
        assert stop_server(srv) == [], "processes outlived the server"


def finished(http: httpx.Client, job_id: str) -> dict[str, Any]:
    deadline = time.monotonic() + JOB_TIMEOUT_S
    while True:
        doc: dict[str, Any] = http.get(f"/api/jobs/{job_id}").json()
        if doc["state"] in ("succeeded", "failed", "cancelled"):
            return doc
        assert time.monotonic() < deadline, f"job still {doc['state']}: {doc}"
        time.sleep(0.2)


def health_seconds(server: Server) -> float:
    t0 = time.perf_counter()
    r = httpx.get(f"{server.url}/api/health", timeout=5.0)
    assert r.status_code == 200
    return time.perf_counter() - t0


def submit(http: httpx.Client, spec: dict[str, Any]) -> str:
    r = http.post("/api/jobs", json=spec)
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def a_worker(server: Server) -> int:
    deadline = time.monotonic() + 60
    while not (pids := worker_pids(server.data_dir)):
        assert time.monotonic() < deadline, f"no worker:\n{server.log_tail()}"
        time.sleep(0.1)
    return pids[0]


@pytest.mark.parametrize(
    ("how", "gib"),
    [("numpy", 8.0), ("drjit", 2.0)],
    ids=["numpy-MemoryError", "drjit-SIGSEGV"],
)
def test_job_past_the_limit_fails_out_of_memory_and_the_next_runs(
    server: Server, how: str, gib: float
) -> None:
    with server.http() as http:
        before = a_worker(server)
        job_id = submit(http, {"kind": "test.alloc", "params": {"how": how, "gib": gib}})
        doc = finished(http, job_id)
        assert doc["state"] == "failed", (doc, server.log_tail())
        assert doc["error"].startswith("out of memory in test.alloc"), doc["error"]
        assert f"{LIMIT_MB} MiB" in doc["error"], doc["error"]
        assert doc["attempts"] == 1, "a job that ran out of memory was retried"
        assert health_seconds(server) < 1.0

        # the worker that ran it is gone, another took its place
        deadline = time.monotonic() + 60
        while before in worker_pids(server.data_dir) or not worker_pids(server.data_dir):
            assert time.monotonic() < deadline, f"worker not replaced:\n{server.log_tail()}"
            time.sleep(0.1)

        seed = {"numpy": 1, "drjit": 2}[how]
        render = finished(http, submit(http, {**SMOKE_RENDER, "seed": seed}))
        assert render["state"] == "succeeded", (render, server.log_tail())
        assert health_seconds(server) < 1.0
