"""Result rows (:mod:`jobapi.rows`): the row's JSON and CSV forms, which metrics are errors,
and what counts as a measured number."""

from __future__ import annotations

import csv
import io
import json

from jobapi.rows import COLUMNS, ResultRow, lower_is_better, number


def test01_document_and_csv() -> None:
    row = ResultRow(
        job="a" * 32,
        kind="score",
        metric="flip",
        value=0.25,
        lower_is_better=True,
        candidate="net16",
        config={"spp": 16, "source": "model"},
        spp=16,
    )
    doc = row.document()
    assert list(doc) == list(COLUMNS)
    assert doc["config"] == {"spp": 16, "source": "model"} and doc["render_seconds"] is None
    cells = row.csv_cells()
    assert json.loads(cells["config"]) == {"source": "model", "spp": 16}
    assert cells["render_seconds"] == "" and cells["value"] == "0.25"
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(COLUMNS))
    writer.writeheader()
    writer.writerow(cells)
    (back,) = csv.DictReader(io.StringIO(buf.getvalue()))
    assert float(back["value"]) == 0.25 and back["candidate"] == "net16"
    assert ResultRow(**doc) == row  # the JSON form reads back
    assert row.with_(step="s").step == "s" and row.step is None


def test02_lower_is_better() -> None:
    assert lower_is_better("flip") is True and lower_is_better("smape") is True
    assert lower_is_better("psnr") is False and lower_is_better("ssim") is False
    assert lower_is_better("C_warp.rel") is True and lower_is_better("rgb.mse") is True
    assert lower_is_better("mean_r") is None


def test03_number() -> None:
    assert number(3) == 3.0 and number(0.5) == 0.5
    assert number(True) is None and number("1") is None and number(None) is None
    assert number(float("nan")) is None and number(float("inf")) is None
