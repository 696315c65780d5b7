"""The links ``make demo`` prints after its batch (``scripts/demo_links.sh``), read from a
results file written as ``matforge batch --out`` writes it (``write_rows``: the columns of
:data:`jobapi.rows.COLUMNS`, a step's job in ``job``, rows only for steps that succeeded).
``matforge`` itself is a stub that lists the fabric job's artifacts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from service.cli.results_command import write_rows

ROOT = Path(__file__).resolve().parents[3]
FABRIC, GLINT, BTF = "f" * 32, "a" * 32, "b" * 32


def row(job: str, step: str, kind: str, metric: str) -> dict[str, object]:
    return {"job": job, "step": step, "kind": kind, "metric": metric, "value": 1.0}


def links(tmp_path: Path, rows: list[dict[str, object]]) -> list[str]:
    results = tmp_path / "demo-results.csv"
    write_rows(results, rows)
    stub = tmp_path / "matforge"
    listing = json.dumps([{"name": "preview.png", "digest": "sha256:" + "c" * 64}])
    stub.write_text(f"#!/bin/sh\n[ \"$1 $2\" = 'artifacts {FABRIC}' ] && echo '{listing}'\n")
    stub.chmod(0o755)
    out = subprocess.run(
        ["bash", "scripts/demo_links.sh", str(results), "http://127.0.0.1:8000"],
        cwd=ROOT,
        env={"MF": str(stub), "PY": sys.executable, "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return out.stdout.splitlines()


def test01_fabric_glint_and_btf_links(tmp_path: Path) -> None:
    rows = [
        row("1" * 32, "gold", "render", "mean"),
        row(FABRIC, "fabric", "generate.fabric", "queries"),
        row(FABRIC, "fabric", "generate.fabric", "materials"),
        row(GLINT, "glint", "generate.glint", "ndf_mean"),
        row(BTF, "btf", "generate.btf", "slices"),
    ]
    assert links(tmp_path, rows) == [
        f"Fabric dataset: http://127.0.0.1:8000/jobs/{FABRIC}",
        "Fabric preview: http://127.0.0.1:8000/api/artifacts/sha256:" + "c" * 64
        + "   (preview.png)",
        f"Glint example and NDF maps: http://127.0.0.1:8000/jobs/{GLINT}"
        "   (example.exr, ndf.npz, preview.png)",
        f"BTF slices: http://127.0.0.1:8000/jobs/{BTF}   (slices-XXXX.npz, btf.json, preview.png)",
    ]  # fmt: skip


def test02_a_step_without_rows_gets_no_link(tmp_path: Path) -> None:
    assert links(tmp_path, [row(GLINT, "glint", "generate.glint", "ndf_mean")]) == [
        f"Glint example and NDF maps: http://127.0.0.1:8000/jobs/{GLINT}"
        "   (example.exr, ndf.npz, preview.png)"
    ]


def test03_demo_sh_prints_them() -> None:
    """``make demo`` runs this script on the file its batch wrote."""
    text = (ROOT / "scripts" / "demo.sh").read_text()
    assert '--out "$DATA/demo-results.csv"' in text
    assert 'bash scripts/demo_links.sh "$DATA/demo-results.csv" "$URL"' in text
