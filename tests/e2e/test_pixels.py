"""``GET /api/artifacts/{digest}/pixels`` (issue 26 §2): the pixel values the compare view
reads under the cursor and subtracts for its difference image, on the grid of the preview."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from evaluators.metrics.tonemap import magma
from service.api import create_app
from service.settings import Settings
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png

OCTETS = {"content-type": "application/octet-stream"}


def _values(response) -> np.ndarray:  # type: ignore[no-untyped-def]
    w, h = int(response.headers["x-image-width"]), int(response.headers["x-image-height"])
    return np.frombuffer(response.content, dtype="<f4").reshape(h, w, 3)


def test01_exr_png_and_flip_map_values(tmp_path: Path) -> None:
    """References: the EXR's own float32 pixels (every k-th, as the preview strides them),
    the PNG's 8-bit levels / 255, and the values the FLIP map was coloured from."""
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    y, x = np.mgrid[0:6, 0:10].astype(np.float32)
    rgb = np.stack([x * 0.5, y * 2.0, x * y / 7.0], axis=-1).astype(np.float32)
    levels = np.arange(60, dtype=np.uint8).reshape(6, 10, 1) * np.array([4, 2, 1], np.uint8)
    err = np.linspace(0.0, 1.0, 60).reshape(6, 10)

    def up(client: TestClient, name: str, body: bytes) -> str:
        r = client.post(f"/api/artifacts?name={name}", content=body, headers=OCTETS)
        assert r.status_code == 201, r.text
        return r.json()["digest"]

    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        exr = up(client, "a.exr", exr_bytes(rgb))
        png = up(client, "b.png", write_png(None, levels))
        flip = up(client, "flip_x.png", write_png(None, magma(err)))
        r = client.get(f"/api/artifacts/{exr}/pixels")
        assert r.status_code == 200 and r.headers["x-image-values"] == "linear"
        np.testing.assert_array_equal(_values(r), rgb)  # float32 both: exactly the file's
        r = client.get(f"/api/artifacts/{png}/pixels?values=srgb")
        np.testing.assert_allclose(_values(r), levels / 255.0, atol=1e-6)
        r = client.get(f"/api/artifacts/{flip}/pixels?values=magma")
        got = _values(r)
        assert np.all(got[..., 0] == got[..., 2])
        assert float(np.abs(got[..., 0] - err).max()) <= 0.5 / 255 + 1e-6
        # the wrong form is refused naming the file; an unknown form is a 422 too
        r = client.get(f"/api/artifacts/{png}/pixels?values=linear")
        assert r.status_code == 422 and "b.png" in r.json()["error"], r.text
        r = client.get(f"/api/artifacts/{exr}/pixels?values=srgb")
        assert r.status_code == 422 and "a.exr" in r.json()["error"], r.text
        assert client.get(f"/api/artifacts/{exr}/pixels?values=rgb").status_code == 422
