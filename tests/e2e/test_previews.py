"""EXR previews (issue 21, item 3): decoded once, in a memory-capped checker child, to a
thumbnail that every exposure is tone-mapped from; images over the preview pixel cap are
refused from their header; the look is the one previews always had."""

from __future__ import annotations

import io
import threading
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import OpenEXR
import pytest
from fastapi.testclient import TestClient

from evaluators.metrics.tonemap import tonemap
from service.api import create_app
from service.previews import PreviewMaker
from service.settings import Settings
from service.upload_check import UploadChecker
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png

from .harness import Server, cmdline, descendants, start_server, stop_server

OCTETS = {"content-type": "application/octet-stream"}


def _gradient(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    return np.stack([x / w * 4.0, y / h, (x + y) % 7 / 3.0], axis=-1).astype(np.float32)


def test01_one_decode_for_every_exposure_and_the_same_look(tmp_path: Path) -> None:
    """Three exposures asked at once: one decode (in the checker child), and each PNG is
    byte for byte ``tonemap`` of the strided thumbnail at that exposure, as before."""
    rgb = _gradient(30, 40)
    path = tmp_path / "g.exr"
    path.write_bytes(exr_bytes(rgb))
    checker = UploadChecker(512 * 1024 * 1024)
    maker = PreviewMaker(checker, max_side=16)  # 40 px wide: every 3rd pixel
    sources = []

    def source() -> tuple[Path, str]:
        sources.append(1)
        return path, "g.exr"

    exposures = [-1.0, 0.0, 2.5]
    got: dict[float, bytes] = {}
    try:
        threads = [
            threading.Thread(target=lambda e=e: got.__setitem__(e, maker.png("d", e, source)))
            for e in exposures
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
        assert maker.png("d", 0.0, source) == got[0.0]
        assert maker.png("d", 1.0, source)  # a new exposure: no new decode
        assert (maker.decodes, len(sources), checker.calls) == (1, 1, 1)
    finally:
        checker.close()
    for e in exposures:
        assert got[e] == write_png(None, tonemap(rgb[::3, ::3], exposure=e))
    assert len(set(got.values())) == 3


def test02_preview_pixel_cap_is_422_naming_the_sizes(tmp_path: Path) -> None:
    settings = Settings.from_env({}).with_(data_dir=tmp_path, preview_max_pixels=100)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        big = client.post(
            "/api/artifacts?name=cap.exr", content=exr_bytes(_gradient(10, 16)), headers=OCTETS
        ).json()["digest"]
        small = client.post(
            "/api/artifacts?name=ok.exr", content=exr_bytes(_gradient(10, 10)), headers=OCTETS
        ).json()["digest"]
        for _ in range(2):  # the second answer comes from the cache of refusals
            r = client.get(f"/api/artifacts/{big}/preview.png", params={"exposure": 1})
            assert r.status_code == 422, r.text
            assert r.json()["error"] == (
                "cap.exr: image of 16x10 pixels is too large to preview (the limit is 100 "
                "pixels, MATFORGE_PREVIEW_MAX_PIXELS); download it instead"
            )
        r = client.get(f"/api/artifacts/{small}/preview.png")
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"


# -- against matforge serve --http-workers 2 ------------------------------------------------
@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = start_server(tmp_path_factory.mktemp("previews"), workers=0, http_workers=2)
    try:
        yield srv
    finally:
        assert stop_server(srv) == []


def _status_kb(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise AssertionError(f"no {field} in /proc/{pid}/status")


def _web_processes(server: Server) -> list[int]:
    extra = [
        p
        for p in descendants(server.proc.pid)
        if "spawn_main" in cmdline(p) and "resource_tracker" not in cmdline(p)
    ]
    return [server.proc.pid, *extra]


def _half_exr(h: int, w: int) -> bytes:
    """A half-float EXR of a flat grey ``h x w`` image (half the test's memory of float32;
    decoding it still gives ``h * w * 12`` bytes of float32)."""
    buf = io.BytesIO()
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": np.full((h, w, 3), 0.5, np.float16)}) as f:
        f.write(buf)
    return buf.getvalue()


def test03_web_process_memory_stays_flat(served: Server) -> None:
    """A 4096x2048 EXR (100 MB of float32 pixels, a small file) previewed at three exposures
    at once: no web process's peak RSS grows by 80 MB. Decoded in the web process, as before
    the fix, the image alone is 100 MB there (plus its channel planes)."""
    web = _web_processes(served)
    assert len(web) == 2
    small = httpx.post(
        f"{served.url}/api/artifacts?name=small.exr", content=exr_bytes(_gradient(8, 8))
    ).json()["digest"]
    for e in range(8):  # warm both processes: the tone curve's imports (colour, ~40 MB)
        assert httpx.get(f"{served.url}/api/artifacts/{small}/preview.png?exposure={e}").is_success
    r = httpx.post(
        f"{served.url}/api/artifacts?name=big.exr", content=_half_exr(2048, 4096), timeout=120
    )
    assert r.status_code == 201, r.text
    big = r.json()["digest"]
    before = {p: _status_kb(p, "VmRSS") for p in web}
    try:
        for p in web:  # "5": reset the peak RSS (VmHWM) to the current RSS
            Path(f"/proc/{p}/clear_refs").write_text("5")
    except OSError as exc:
        pytest.skip(f"cannot reset the peak RSS here: {exc}")
    codes: dict[float, int] = {}

    def get(e: float) -> None:
        url = f"{served.url}/api/artifacts/{big}/preview.png?exposure={e}"
        codes[e] = httpx.get(url, timeout=120).status_code

    threads = [threading.Thread(target=get, args=(e,)) for e in (-2.0, 0.0, 2.0)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=180)
    assert codes == {-2.0: 200, 0.0: 200, 2.0: 200}
    growth_mb = {p: (_status_kb(p, "VmHWM") - before[p]) / 1024 for p in web}
    assert max(growth_mb.values()) < 80, growth_mb
