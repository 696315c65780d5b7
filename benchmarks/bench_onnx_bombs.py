"""ONNX graphs that ask for memory out of proportion to their file: what the upload check
says, what it costs, and what evaluating the graphs it lets through costs.

Graphs (built with ``onnx.helper`` in :mod:`tests.helpers.onnx_models`):

- ``fold-16384``, ``fold-65536``: the constant-folding bomb, ``[K, 1]`` and ``[1, K]``
  initialisers added to ``[K, K]`` (1 GiB and 16 GiB of float32 from 128 KiB and 512 KiB
  files), which onnxruntime computes when it opens the model;
- ``square``: the run-time quadratic, ``Slice(wi) [N, 1] -> Transpose -> Add [N, N]``;
- ``hidden-square``: the same square with its column cut to a value-dependent width, so
  that shape inference cannot size it: the check lets it through, and only the evaluation's
  chunks bound it;
- ``mlp``: a torch MLP (9 -> 64 -> 64 -> 3) exported by ``matforge.export_onnx.brdf_onnx``.

Each graph runs in a fresh process: :func:`storage.formats.validate_file` (the check of
``POST /api/artifacts`` and ``matforge import``), then, for a graph it accepts,
:class:`models.external.onnx_model.OnnxMaterial` on ``--rows`` rows (a render's batch).
Prints one row per graph (outcome, check seconds, evaluation seconds and calls, peak RSS of
the process) and the command that reproduces it.

Run: ``.venv/bin/python benchmarks/bench_onnx_bombs.py [--rows 262144]``
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
GRAPHS = ("fold-16384", "fold-65536", "square", "hidden-square", "mlp")


def _model(name: str, folder: Path) -> Path:
    from tests.helpers import onnx_models as om

    if name == "mlp":
        import torch

        from matforge.export_onnx import brdf_onnx

        class Mlp(torch.nn.Module):
            def __init__(self) -> None:
                super().__init__()
                self.net = torch.nn.Sequential(
                    torch.nn.Linear(9, 64), torch.nn.ReLU(), torch.nn.Linear(64, 64),
                    torch.nn.ReLU(), torch.nn.Linear(64, 3),
                )  # fmt: skip

            def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
                h = torch.nn.functional.normalize(wi + wo, dim=1)
                return torch.exp(self.net(torch.cat([wi, wo, h], 1)))

        torch.manual_seed(0)
        return brdf_onnx(Mlp(), folder / "mlp.onnx")
    make = {
        "fold-16384": lambda: om.constant_fold_bomb(16384),
        "fold-65536": lambda: om.constant_fold_bomb(65536),
        "square": om.quadratic_bomb,
        "hidden-square": om.hidden_square_model,
    }[name]
    return om.save(make(), folder / f"{name}.onnx")


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _one(name: str, rows: int, out: Any) -> None:
    sys.path.insert(0, str(ROOT))
    import numpy as np

    from models.external.onnx_model import load_onnx
    from storage.errors import FormatError, TooLargeError
    from storage.formats import validate_file

    with tempfile.TemporaryDirectory() as d:
        path = _model(name, Path(d))
        size = path.stat().st_size
        start_mib = _peak_mib()
        t = time.perf_counter()
        try:
            validate_file(path, path.name)
            outcome = "accepted"
        except TooLargeError as exc:
            outcome = f"413: {str(exc).split(': ', 1)[1][:70]}"
        except FormatError as exc:
            outcome = f"422: {exc.problem[:70]}"
        check_s = time.perf_counter() - t
        row: dict[str, Any] = {"graph": name, "file_kb": size / 1024, "outcome": outcome,
                               "check_s": check_s, "start_mib": start_mib}  # fmt: skip
        if outcome == "accepted":
            m = load_onnx(path, "brdf", threads=2)
            v = np.random.default_rng(0).normal(size=(rows, 3)).astype(np.float32)
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            t = time.perf_counter()
            m.eval(v, v)
            row.update(eval_s=time.perf_counter() - t, calls=m.stats.calls, chunk=m.chunk)
        row["peak_mib"] = _peak_mib()
        out.put(row)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1 << 18, help="rows per evaluation")
    ap.add_argument("--graphs", default=",".join(GRAPHS))
    args = ap.parse_args()
    ctx = mp.get_context("spawn")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}; rows {args.rows}")  # fmt: skip
    print("| graph | file | upload check | check s | eval s (calls x rows) | peak RSS MiB |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in args.graphs.split(","):
        q = ctx.Queue()
        p = ctx.Process(target=_one, args=(name, args.rows, q))
        p.start()
        row = q.get(timeout=600)
        p.join()
        ev = (f"{row['eval_s']:.2f} ({row['calls']} x {row['chunk']})" if "eval_s" in row
              else "-")  # fmt: skip
        print(f"| {row['graph']} | {row['file_kb']:.0f} KiB | {row['outcome']} | "
              f"{row['check_s']:.3f} | {ev} | {row['peak_mib']:.0f} |")  # fmt: skip
    print(f"# load {os.getloadavg()[0]:.1f}; command: .venv/bin/python "
          f"benchmarks/bench_onnx_bombs.py --rows {args.rows} --graphs {args.graphs}")  # fmt: skip


if __name__ == "__main__":
    main()
