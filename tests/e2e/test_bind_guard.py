"""Listening on every interface (issue 21, item 11, and the Docker user of item 4).

``allowed_hosts('0.0.0.0', [])`` is ``None``: bound to every interface with no configured host
names, the server cannot check ``Host`` and DNS rebinding reaches the API. ``serve`` refuses to
start so (exit 2, naming ``MATFORGE_ALLOWED_HOSTS``); the Docker files publish the port on
127.0.0.1 only, configure the host names and run the server as a user that is not root.

Nothing here listens on anything but 127.0.0.1: the refused start is given a port that a
socket of this test holds on 127.0.0.1, so a server that did not refuse could not bind either
(it would fail in another way, and the test with it).
"""

from __future__ import annotations

import re
import socket
import subprocess
from pathlib import Path

import yaml

from service.web_guard import allowed_hosts, bind_refusal

from .harness import REPO, base_env, matforge_exe

DOCKER = REPO / "docker"


def test01_serve_on_all_interfaces_without_allowed_hosts_exits_2(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", 0))
        held.listen(1)
        port = held.getsockname()[1]
        proc = subprocess.run(
            [matforge_exe(), "serve", "--host", "0.0.0.0", "--port", str(port), "--workers",
             "0", "--data-dir", str(tmp_path / "d")],
            env=base_env(), capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "MATFORGE_ALLOWED_HOSTS" in proc.stderr and "0.0.0.0" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test02_bind_refusal_rules() -> None:
    for host in ("0.0.0.0", "::", "[::]", ""):
        assert bind_refusal(host, ()) is not None, host
        assert allowed_hosts(host, ()) is None  # what the refusal protects against
        assert bind_refusal(host, ("matforge.lab",)) is None
        assert bind_refusal(host, ("*",)) is None  # the check turned off knowingly
        assert bind_refusal(host, (" ",)) is not None  # an empty entry configures nothing
    for host in ("127.0.0.1", "::1", "localhost", "10.0.0.5"):
        assert bind_refusal(host, ()) is None, host  # a named address checks Host itself


def _compose_files() -> list[Path]:
    files = sorted(DOCKER.glob("compose*.yaml"))
    assert files, "no docker/compose*.yaml"
    return files


def test03_compose_publishes_on_loopback_only() -> None:
    for path in _compose_files():
        doc = yaml.safe_load(path.read_text())
        for name, service in doc["services"].items():
            for port in service.get("ports", []):
                assert str(port).startswith("127.0.0.1:"), f"{path.name}: {name} publishes {port}"


def test04_containers_serving_on_all_interfaces_configure_hosts() -> None:
    dockerfile = (DOCKER / "Dockerfile").read_text()
    env_hosts = re.search(r"MATFORGE_ALLOWED_HOSTS=(\S+)", dockerfile)
    for path in _compose_files():
        doc = yaml.safe_load(path.read_text())
        for name, service in doc["services"].items():
            command = str(service.get("command", ""))
            if "matforge serve" in command or (name == "matforge" and not command):
                hosts = (service.get("environment") or {}).get("MATFORGE_ALLOWED_HOSTS")
                assert hosts or env_hosts, f"{path.name}: {name} would refuse to start"
    assert env_hosts and '--host", "0.0.0.0"' in dockerfile


def test05_docker_image_runs_as_a_user_that_is_not_root() -> None:
    lines = [ln.strip() for ln in (DOCKER / "Dockerfile").read_text().splitlines()]
    users = [ln.split(None, 1)[1] for ln in lines if ln.startswith("USER ")]
    assert users, "the image runs as root (no USER)"
    assert users[-1].split(":")[0] not in ("root", "0"), users
    assert any("chown" in ln and "/data" in ln for ln in lines), "the data dir is root's"
