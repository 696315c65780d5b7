"""One Ray per test session: a local instance, or a simulated cluster of several nodes.

Ray starts in about 5 s, so the tests share one instance (the ``ray_local`` fixture); a test
that needs several nodes (``ray.cluster_utils.Cluster``) replaces it for its duration, and
the next ``ray_local`` starts a local one again. Everything runs on this machine, with token
authentication on (a random token in the environment, never written under ``~/.ray``) and
no dashboard. :meth:`RaySession.shutdown` ends every Ray process the session started.
"""

from __future__ import annotations

import secrets
from typing import Any

import pytest
import ray
from ray._private.authentication_test_utils import reset_auth_token_state
from ray.cluster_utils import Cluster

#: Small object stores: the tests' shards return a few kilobytes each.
OBJECT_STORE_BYTES = 128 * 1024 * 1024


class RaySession:
    """Which Ray this test process is connected to: ``None``, ``"local"`` or a cluster."""

    def __init__(self) -> None:
        self.mode: str | None = None
        self.cluster: Cluster | None = None
        self._env = pytest.MonkeyPatch()
        # Ray >= 2.52: token auth, as a deployment should run it (docs/ray.md).
        self._env.setenv("RAY_AUTH_MODE", "token")
        self._env.setenv("RAY_AUTH_TOKEN", secrets.token_hex(16))
        reset_auth_token_state()  # Ray read its config at import, before these were set

    def local(self, num_cpus: int = 2) -> None:
        """A local Ray of ``num_cpus`` CPUs (kept if it is already the one running)."""
        if self.mode == "local" and ray.is_initialized():
            return
        self.shutdown(keep_env=True)
        ray.init(
            address="local",
            num_cpus=num_cpus,
            include_dashboard=False,
            object_store_memory=OBJECT_STORE_BYTES,
            configure_logging=False,
            log_to_driver=False,
        )
        self.mode = "local"

    def start_cluster(self, nodes: int = 2) -> Cluster:
        """A head and ``nodes - 1`` worker nodes of one CPU each, this process connected."""
        self.shutdown(keep_env=True)
        args: dict[str, Any] = {
            "num_cpus": 1,
            "include_dashboard": False,
            "object_store_memory": OBJECT_STORE_BYTES,
        }
        # Notice a removed node within about a second (Ray's default takes ~15 s).
        fast_health_check = {
            "health_check_initial_delay_ms": 0,
            "health_check_period_ms": 250,
            "health_check_timeout_ms": 250,
            "health_check_failure_threshold": 3,
        }
        cluster = Cluster(
            initialize_head=True, head_node_args={**args, "_system_config": fast_health_check}
        )
        self.cluster, self.mode = cluster, "cluster"
        for _ in range(nodes - 1):
            cluster.add_node(num_cpus=1, object_store_memory=OBJECT_STORE_BYTES)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, configure_logging=False, log_to_driver=False)
        return cluster

    def shutdown(self, keep_env: bool = False) -> None:
        """Disconnect and stop every Ray process this session started."""
        if ray.is_initialized():
            ray.shutdown()
        if self.cluster is not None:
            self.cluster.shutdown()
            self.cluster = None
        self.mode = None
        if not keep_env:
            self._env.undo()
            reset_auth_token_state()
