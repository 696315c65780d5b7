"""The CLI's tables at 80, 100 and 200 columns (``COLUMNS``, as a terminal sets it) and
piped (no ``COLUMNS``: :data:`service.cli.state.PIPE_WIDTH`): every line fits, no header or
cell is cut into pieces, no column is squeezed to nothing.

The pivot's rows are shaped as the demo batch's are (renders' image statistics, a score's
candidates, datasets' own statistics, a MERL collection's table quality, a trained hybrid's
per-material scores and costs): 33 columns, which at 100 columns gave 33 zero-width
columns and at 250 headers chopped into pieces of 2-4 letters, the MERL table-quality
columns among the methods'. The reference is the rows' own text: each header and each
number appears whole on one line.
"""

from __future__ import annotations

import re
from typing import Any

import pytest

from service.cli.results_command import show_pivot

WIDTHS = [80, 100, 200, None]  # None: piped


def _row(step: str, kind: str, metric: str, value: float, **kw: Any) -> dict[str, Any]:
    return {"job": (step * 32)[:32], "step": step, "kind": kind, "metric": metric,
            "value": value, "lower_is_better": kw.pop("lib", None), **kw}  # fmt: skip


def demo_rows() -> list[dict[str, Any]]:
    rows = []
    # (the demo's render step "plastic" is also a score candidate: one method of the pivot
    # then, whose renders' and scores' columns are one table; named apart here)
    for step in ("gold", "gold_16spp", "gold_rougher", "orange", "glint_render"):
        for metric, value in (("image.mean", 0.31), ("image.max", 4.2), ("image.nan_pixels", 0)):
            rows.append(_row(step, "render", metric, value, render_seconds=2.5, spp=256))
    for cand, flip in (("noisy_16spp", 0.05), ("rougher", 0.08), ("plastic", 0.31)):
        for metric, value, lib in (("flip", flip, True), ("psnr", 30 - 40 * flip, False),
                                   ("ssim", 1 - flip, False), ("image.smape", flip / 2, True),
                                   ("image.mae", flip / 10, True)):  # fmt: skip
            rows.append(_row("scores", "score", metric, value, candidate=cand, lib=lib))
    for metric in ("fabric.queries", "fabric.materials", "fabric.rel_stderr_median"):
        rows.append(_row("fabric", "generate.fabric", metric, 1280.0))
    for metric in ("glint.ndf_integral", "glint.slope_rms", "glint.texels"):
        rows.append(_row("glint", "generate.glint", metric, 1.0))
    for metric in ("btf.slices", "btf.texels", "btf.mean_reflectance"):
        rows.append(_row("btf", "generate.btf", metric, 0.2))
    for metric in ("tabulation.missing_bins", "tabulation.reciprocity_error",
                   "tabulation.energy_max", "tabulation.negative_bins"):  # fmt: skip
        rows.append(_row("tables", "generate.merl", metric, 0.0, lib=True))
    for mat in ("gold", "film", "plastic"):
        for metric in ("brdf.smape", "brdf.smape_floor", "brdf.mae", "brdf.smape_analytic",
                       "brdf.smape_floor_analytic", "brdf.mae_analytic"):  # fmt: skip
            costs = {"train_seconds": 40.0, "bytes_per_material": 44.0, "ns_per_eval": 61.0}
            rows.append(_row("hybrid", "train.brdf", metric, 0.12, material=mat, lib=True, **costs))
    return rows


def _printed(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], width: int | None
) -> tuple[str, int]:
    from service.cli.state import PIPE_WIDTH

    if width is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", str(width))
    show_pivot(demo_rows(), "candidate", None, False)
    return capsys.readouterr().out, width or PIPE_WIDTH


@pytest.mark.parametrize("width", WIDTHS)
def test01_pivot_fits_with_whole_headers(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], width: int | None
) -> None:
    text, limit = _printed(monkeypatch, capsys, width)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= limit, (width, max(map(len, lines)))
    metrics = {r["metric"] for r in demo_rows()}
    for name in metrics | {"train_seconds", "ns_per_eval", "bytes_per_material"}:
        assert re.search(rf"(^|[\s│┃]){re.escape(name)}([\s│┃]|$)", text, re.M), (width, name)
    for method in ("gold_16spp", "noisy_16spp", "glint_render", "tables", "hybrid"):
        assert method in text, (width, method)
    assert "0.12 ± 0" in text  # a hybrid's mean and spread, whole
    # no column squeezed to nothing: no empty cell between two borders
    assert not re.search(r"[│┃][│┃]", text), width


@pytest.mark.parametrize("width", WIDTHS)
def test02_table_quality_is_not_among_the_methods_metrics(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], width: int | None
) -> None:
    """The MERL collection's table quality, the datasets' statistics and the methods'
    scores are separate tables: no line holds a table-quality and a method's column."""
    text, _ = _printed(monkeypatch, capsys, width)
    tables = re.split(r"\n(?=\s*\d+ methods by)", text)
    quality = [t for t in tables if "tabulation.missing_bins" in t]
    assert quality and all("brdf.smape" not in t and "flip" not in t for t in quality), text
    scores = [t for t in tables if "noisy_16spp" in t]
    assert scores and all("tabulation" not in t and "image.mean" not in t for t in scores)


def _console(monkeypatch: pytest.MonkeyPatch, width: int | None) -> tuple[Any, int]:
    """A console as the commands make one on stdout (``out_console``), and its width."""
    from service.cli.state import PIPE_WIDTH, out_console

    if width is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", str(width))
    console = out_console()
    assert console.width == (width or PIPE_WIDTH)
    return console, console.width


def demo_steps() -> list[Any]:
    """The demo batch's steps, with result tables shaped as their kinds' summaries are."""
    from jobapi.results import ResultTable
    from service.cli.batch import StepResult

    render = ResultTable("Render", "Scene", ["width", "height", "spp", "mean_r", "max"],
                         {"sphere_env": {"width": 256, "height": 256, "spp": 256,
                                         "mean_r": 0.3, "max": 4.0}})  # fmt: skip
    score = ResultTable("Scores", "Candidate", ["flip", "psnr", "ssim"],
                        {c: {"flip": f, "psnr": 30.0, "ssim": 0.9}
                         for c, f in (("noisy_16spp", 0.05), ("rougher", 0.08))})  # fmt: skip
    merl = ResultTable("Materials", "Material", ["family", "source", "tabulation.missing_bins"],
                       {f"iridescent-00{i}-Au": {"family": "iridescent", "source": "analytic",
                                                 "tabulation.missing_bins": 0}
                        for i in range(12)})  # fmt: skip
    brdf = ResultTable("Metrics per material", "Material", ["family", "split", "smape", "mae"],
                       {"gold": {"family": "metal", "split": "train", "smape": 0.1, "mae": 0.01},
                        "film": {"family": "iridescent", "split": "heldout", "smape": 0.12,
                                 "mae": 0.02},
                        "mean": {"smape": 0.11, "mae": 0.015}})  # fmt: skip
    steps = [("gold", "render", render), ("gold_rougher", "render", render),
             ("scores", "score", score), ("fabric", "generate.fabric", None),
             ("tables", "generate.merl", merl), ("hybrid", "train.brdf", brdf)]  # fmt: skip
    return [
        StepResult(
            step=s, kind=k, job_id=f"{i:x}" * 32, state="succeeded", seconds=12.5 * i, table=t
        )  # fmt: skip
        for i, (s, k, t) in enumerate(steps, start=1)
    ]


@pytest.mark.parametrize("width", WIDTHS)
def test03_batch_summary_fits_with_its_border_and_a_headline(
    monkeypatch: pytest.MonkeyPatch, width: int | None
) -> None:
    """Every line fits (the right border is there: the table was cropped at the width
    without it); the step, kind, id, state and time are whole; each step's headline is a
    score (a mean when the table has one), or what the table holds, never its first
    column (``width: sphere_env 256``, ``family: iridescent-000-Au ...``)."""
    from service.cli.results import result_rows, results_table

    console, limit = _console(monkeypatch, width)
    steps = demo_steps()
    columns, rows = result_rows(steps)
    with console.capture() as cap:
        console.print(results_table(columns, rows, "batch demo", steps, width=console.width))
    text = cap.get()
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= limit, (width, max(map(len, lines)))
    body = [line for line in lines if line.startswith("│")]
    assert body and all(line.rstrip().endswith("│") for line in body), text
    for r in steps:
        row = next(line for line in lines if r.job_id[:12] in line)
        for cell in (r.step, r.kind, "succeeded", f"{r.seconds:.4g}"):
            assert cell in row, (width, cell, row)
    for start in ("1 scene: sphere_env", "flip: noisy_16spp 0.05", "smape: mean 0.11 (2",
                  "12 materials: iridesc"):  # fmt: skip
        assert start in text, (width, start, text)  # (the line is cut at its column's end)
    assert "width:" not in text and "family:" not in text


@pytest.mark.parametrize("width", WIDTHS)
def test04_progress_keeps_percent_and_state_whole(
    monkeypatch: pytest.MonkeyPatch, width: int | None
) -> None:
    """The batch's progress lines: the step label, the percentage, the times and the state
    are whole (they shrank to ``10…`` and ``succeed…`` at 100 columns); the message is cut
    at its end."""
    from service.cli.follow import add_job_task, make_progress

    console, limit = _console(monkeypatch, width)
    progress = make_progress(console)
    done = add_job_task(progress, "gold_rougher (render)")
    progress.update(done, completed=1.0, state="succeeded",
                    message="rendered 256x256 at 256 spp in 12.3 s; " * 3)  # fmt: skip
    running = add_job_task(progress, "hybrid (train.brdf)")
    progress.update(running, completed=0.1, state="running", eta="ETA 0:01:30",
                    message="epoch 3 of 40: loss 0.0123 " * 3)  # fmt: skip
    with console.capture() as cap:
        console.print(progress.make_tasks_table(progress.tasks))
    lines = cap.get().splitlines()
    assert max(len(line) for line in lines) <= limit
    for words, line in zip(
        [("gold_rougher (render)", "100%", "succeeded", "rendered"),
         ("hybrid (train.brdf)", "10%", "ETA 0:01:30", "running", "epoch")],
        lines, strict=True,
    ):  # fmt: skip
        for word in words:
            assert word in line, (width, word, line)


@pytest.mark.parametrize("width", WIDTHS)
def test05_ls_gives_the_message_room_or_wraps_it(
    monkeypatch: pytest.MonkeyPatch, width: int | None
) -> None:
    """``matforge ls``: names and messages are whole, wrapped at word boundaries, not cut
    to about 8 characters."""
    from service.cli.listing import jobs_table

    from .test_cli_output import _jobs

    console, limit = _console(monkeypatch, width)
    message = "rendering pass 3 of 16: 12.3 s so far, about 40 s left"
    docs = _jobs(message)
    with console.capture() as cap:
        console.print(jobs_table(docs, console.width))
    text = cap.get()
    assert max(len(line) for line in text.splitlines()) <= limit
    assert "…" not in text, text

    def column(header: str) -> list[str]:
        """The words of one column, read down the table."""
        lines = text.splitlines()
        head = next(line for line in lines if header in line)
        start = head.index(header)
        end = head.index("┃", start)
        return " ".join(line[start:end] for line in lines[3:-1]).split()

    words = column("message")
    assert " ".join(words).count(message) == len(docs), words
    assert " ".join(column("name")).count("a fairly long job name for a render") == len(docs)
