"""Screenshots of the dashboard for the docs: a job page of every kind, the job list and the
compare view, taken in headless Chromium from small jobs run here.

Run: ``.venv/bin/python scripts/screenshots.py`` (about 3 minutes on 2 cores). It runs the
smoke job of every built-in kind that has smoke params (inputs first, as the browser tests
make them; renders a little larger, so that their pictures are worth looking at), an
``import.btf`` of a folder of slice images written from a small ``generate.btf`` job,
three renders of different materials and a batch of two training runs for the compare
view, into a temporary data directory;
serves the dashboard there (no workers); and writes 1280-px-wide PNGs, reduced to 256
colours, to ``docs/screenshots/`` (``docs/compare-view.png`` too) and the page that shows
them, ``docs/screenshots.md``. Needs Debian's ``/usr/bin/chromium`` (``make setup``).
``--out DIR`` writes the PNGs elsewhere and leaves the docs alone.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from service import kinds  # noqa: E402
from service.cli.batch import substitute_refs  # noqa: E402
from service.settings import Settings  # noqa: E402
from service.specs import STEP_REF  # noqa: E402
from service.submission import run_in_process  # noqa: E402
from storage.jobs import Job  # noqa: E402
from tests.e2e.harness import serve_in_subprocess  # noqa: E402

CHROMIUM = Path("/usr/bin/chromium")
TOKEN = "screenshots"
WIDTH = 1280
#: The tallest screenshot (a long job page is cut here).
MAX_HEIGHT = 1800
#: Renders at this size rather than the smoke test's 32 x 32 (the score smoke job then
#: compares pictures of this size too).
RENDER = {"resolution": [160, 120], "spp": 16}
#: The compare view's renders: three materials in the same scene.
COMPARE_RENDERS = {
    "diffuse": {"mitsuba": {"type": "diffuse"}},
    "rough gold": {"mitsuba": {"type": "roughconductor", "material": "Au", "alpha": 0.2}},
    "blue plastic": {
        "mitsuba": {
            "type": "roughplastic",
            "alpha": 0.1,
            "diffuse_reflectance": {"type": "rgb", "value": [0.1, 0.25, 0.7]},
        }
    },
}


class Runs:
    """Smoke jobs by kind, inputs first (a ``step:KIND`` ref is that kind's smoke job)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.done: dict[str, Job] = {}

    def job(self, name: str) -> Job:
        if name not in self.done:
            kind = kinds.get_kind(name)

            def resolve(ref: str) -> str:
                m = STEP_REF.match(ref)
                assert m is not None
                dep = self.job(m["step"])
                if dep.state != "succeeded":
                    raise RuntimeError(f"{name} needs {m['step']}, which failed: {dep.error}")
                return f"job:{dep.id}" if m["name"] is None else f"job:{dep.id}/{m['name']}"

            params: dict[str, Any] = substitute_refs(kind.smoke, resolve)
            if name == "render":
                params = {**params, **RENDER}
            spec = {"kind": name, "name": f"{name} (smoke)", "params": params}
            started = time.monotonic()
            self.done[name] = run_in_process(spec, self.settings)
            print(f"  {name}: {self.done[name].state} in {time.monotonic() - started:.1f} s")
        return self.done[name]


def compare_score(settings: Settings) -> Job:
    """A score job of two candidates against a 64-spp reference of rough gold: the same
    material at 4 spp (noise), and a rougher one at 64 spp (a material change)."""
    gold = COMPARE_RENDERS["rough gold"]
    rougher = {"mitsuba": {**gold["mitsuba"], "alpha": 0.35}}

    def render(name: str, material: dict[str, Any], spp: int) -> str:
        params = {"material": material, **RENDER, "spp": spp}
        job = run_in_process({"kind": "render", "name": name, "params": params}, settings)
        if job.state != "succeeded":
            raise RuntimeError(f"render {name} failed: {job.error}")
        return f"job:{job.id}/image.exr"

    params = {
        "reference": render("gold, 64 spp", gold, 64),
        "candidates": {
            "spp4": render("gold, 4 spp", gold, 4),
            "alpha0.35": render("rougher gold, 64 spp", rougher, 64),
        },
    }
    return run_in_process(
        {"kind": "score", "name": "gold: noise and roughness", "params": params}, settings
    )


#: The batch of the methods-table screenshot: two widths of the smoke ``train.brdf`` run.
WIDTHS_BATCH = "brdf widths"


def width_runs(settings: Settings, runs: Runs) -> list[Job]:
    """Two ``train.brdf`` runs (16 and 32 wide) on the smoke MERL dataset, one batch
    (:data:`WIDTHS_BATCH`), for the compare view's method x metric table."""
    merl = runs.job("generate.merl")
    smoke = dict(kinds.get_kind("train.brdf").smoke)
    return [
        run_in_process(
            {
                "kind": "train.brdf",
                "name": f"width {w}",
                "batch": WIDTHS_BATCH,
                "params": {**smoke, "dataset": f"job:{merl.id}", "width": w},
            },
            settings,
        )
        for w in (16, 32)
    ]


#: The ``generate.btf`` job whose slices ``import.btf`` reads back for its screenshot (that
#: kind has no smoke params: it needs an uploaded folder): four light/view pairs of wood.
BTF_SOURCE = {
    "surface": {"procedural": "wood", "size": 32},
    "resolution": 32,
    "spp": 4,
    "directions": [[0, 0, 0, 0], [30, 40, 60, 200], [60, 200, 30, 40], [75, 90, 10, 0]],
}


def import_btf(settings: Settings, tmp: Path) -> Job:
    """An ``import.btf`` job of a folder of slice images, made by the project's own code:
    the slices of a small ``generate.btf`` job (:data:`BTF_SOURCE`) written as a slice folder,
    packed and uploaded as ``matforge import`` does."""
    from generators.btf.slice_folder import job_slice_folder
    from service.submission import import_file
    from storage.artifacts import ArtifactStore
    from storage.formats.btf_folder import pack_folder
    from storage.jobs import JobStore

    source = run_in_process(
        {"kind": "generate.btf", "name": "wood scan (source)", "params": BTF_SOURCE}, settings
    )
    if source.state != "succeeded":
        raise RuntimeError(f"generate.btf for import.btf failed: {source.error}")
    store = ArtifactStore(settings.store_dir)
    folder = job_slice_folder(source.artifacts, store, tmp / "wood_scan")
    jobs = JobStore(settings.db_path)
    try:
        record = import_file(pack_folder(folder, tmp / "wood_scan.btf.zip"), jobs, store)
    finally:
        jobs.close()
    spec = {"kind": "import.btf", "name": "wood scan (imported)",
            "params": {"archive": f"sha256:{record.digest}"}}  # fmt: skip
    return run_in_process(spec, settings)


def small_png(shot: bytes) -> bytes:
    """A screenshot reduced to 256 colours (a tenth of the size; UI colours survive)."""
    import numpy as np
    from PIL import Image

    image = Image.open(io.BytesIO(shot)).convert("RGB")
    pixels = np.asarray(image)
    # cut the page's empty bottom (rows of the background colour), leaving a margin
    busy = np.flatnonzero((pixels != pixels[-1, 0]).any(axis=(1, 2)))
    height = min(MAX_HEIGHT, int(busy[-1]) + 33 if busy.size else image.height, image.height)
    image = image.crop((0, 0, image.width, height))
    out = io.BytesIO()
    image.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
        out, "PNG", optimize=True
    )
    return out.getvalue()


#: A page is ready when its images are loaded (charts draw as their documents arrive).
SETTLED = "() => [...document.images].every(i => i.complete && i.naturalWidth > 0)"


def shoot(pg: Any, url: str, path: Path, wait: str = SETTLED, full: bool = True) -> None:
    pg.goto(url)
    pg.evaluate("window.scrollTo(0, document.body.scrollHeight)")  # lazy images load
    pg.wait_for_function(wait, timeout=30_000)
    pg.evaluate("window.scrollTo(0, 0)")
    pg.wait_for_timeout(1500)  # chart animations
    path.write_bytes(small_png(pg.screenshot(full_page=full)))
    print(f"  {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")


def page_markdown(shots: list[tuple[str, str, str]]) -> str:
    """docs/screenshots.md: each screenshot under a heading, with what it shows."""
    lines = [
        "# Screenshots",
        "",
        "The dashboard as it shows small jobs of every kind: each job page (its lead",
        "picture first, at full size; its charts; its result table), the job list with",
        "parameter and metric columns, and the compare view. Generated by",
        "`scripts/screenshots.py` from the smoke jobs of every kind (renders at 160 x 120;",
        "`import.btf` of a folder of slice images written from a small `generate.btf` job),",
        "at 1280 px wide; pages longer than 1800 px are cut there.",
        "",
    ]
    for title, file, caption in shots:
        lines += [f"## {title}", "", caption, ""]
        if file:  # a kind without a screenshot gets its caption only
            lines += [f"![{title}]({file})", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="write the PNGs here (not the docs)")
    args = ap.parse_args(argv)
    if not CHROMIUM.exists():
        print(f"needs {CHROMIUM} (`make setup`)", file=sys.stderr)
        return 2
    out = args.out or ROOT / "docs" / "screenshots"
    out.mkdir(parents=True, exist_ok=True)
    kinds.load_builtin()
    builtin = sorted(
        (k for k in kinds.all_kinds().values() if kinds.plugin_of(k.name) is None),
        key=lambda k: k.name,
    )
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="matforge-shots-") as tmp:
        data = Path(tmp) / "data"
        (data / "scratch").mkdir(parents=True)
        settings = Settings.from_env({}).with_(data_dir=data, pool_processes=1)
        runs = Runs(settings)
        print("running the smoke job of every kind:")
        for kind in builtin:
            if kind.smoke:
                runs.job(kind.name)
        renders = [
            run_in_process(
                {"kind": "render", "name": label, "params": {"material": m, **RENDER, "spp": 64}},
                settings,
            )
            for label, m in COMPARE_RENDERS.items()
        ]
        score = compare_score(settings)
        started = time.monotonic()
        extra = {"import.btf": import_btf(settings, Path(tmp))}  # kinds without smoke params
        widths = width_runs(settings, runs)
        print(f"  import.btf: {extra['import.btf'].state} in {time.monotonic() - started:.1f} s")
        failed = {n: j.error for n, j in runs.done.items() if j.state != "succeeded"}
        failed |= {j.name or j.id: j.error for j in [*renders, score, *extra.values(), *widths]
                   if j.state != "succeeded"}  # fmt: skip
        if failed:
            print(f"jobs failed: {failed}", file=sys.stderr)
            return 1
        shots: list[tuple[str, str, str]] = []
        with (
            serve_in_subprocess(data, TOKEN, Path(tmp) / "server.log") as (url, _),
            sync_playwright() as pw,
        ):
            browser = pw.chromium.launch(
                executable_path=str(CHROMIUM), args=["--headless", "--no-sandbox"]
            )
            pg = browser.new_context(viewport={"width": WIDTH, "height": 900}).new_page()
            pg.goto(f"{url}/?token={TOKEN}")  # the session cookie
            print("screenshots:")
            for kind in builtin:
                job = runs.done.get(kind.name) or extra.get(kind.name)
                if job is None:
                    shots.append(
                        (
                            f"`{kind.name}`",
                            "",
                            f"{kind.description} (No screenshot: "
                            "the kind has no smoke params; it needs measured data.)",
                        )
                    )
                    continue
                file = f"job-{kind.name.replace('.', '-')}.png"
                shoot(pg, f"{url}/jobs/{job.id}", out / file)
                shots.append((f"`{kind.name}`", f"screenshots/{file}", kind.description))
            rows = "() => document.querySelectorAll('#jobs-body tr[data-id]').length > 0"
            cols = "columns=params.model,params.spp,metric.brdf.smape,metric.image.flip&group=1"
            shoot(pg, f"{url}/?{cols}", out / "jobs.png", wait=rows, full=False)
            shots.append(
                (
                    "The job list",
                    "screenshots/jobs.png",
                    "Every job above, grouped by batch, with two parameter and two metric "
                    "columns (`?columns=params.model,params.spp,metric.brdf.smape,"
                    "metric.image.flip`); filters such as `params.model=hybrid` or "
                    "`metric.brdf.smape<0.1` go in the Filter box.",
                )
            )
            ids = ",".join(j.id[:12] for j in renders)
            compare = out / "compare-renders.png"
            shoot(pg, f"{url}/compare?jobs={ids}", compare, full=False)
            shots.append(
                (
                    "The compare view: three renders",
                    "screenshots/compare-renders.png",
                    "Three materials in one scene side by side, with linked zoom and "
                    "pan and the exposure slider.",
                )
            )
            if score is not None:
                shoot(
                    pg, f"{url}/compare?jobs={score.id[:12]}", out / "compare-score.png", full=False
                )
                shots.append(
                    (
                        "The compare view: a score job",
                        "screenshots/compare-score.png",
                        "A score job's reference and its two candidates (the same gold at 4 spp, a "
                        "rougher gold), paired by role.",
                    )
                )
                shoot(
                    pg,
                    f"{url}/compare?jobs={score.id[:12]}&picture=diff",
                    out / "compare-score-diff.png",
                    full=False,
                )
                shots.append(
                    (
                        "The compare view: the difference",
                        "screenshots/compare-score-diff.png",
                        "The signed difference of each candidate to the reference, under "
                        "one colour bar.",
                    )
                )
            batch = WIDTHS_BATCH.replace(" ", "+")
            shoot(pg, f"{url}/compare?batch={batch}", out / "compare-batch-methods.png")
            shots.append(
                (
                    "The compare view: a batch's methods",
                    "screenshots/compare-batch-methods.png",
                    "A batch of two training runs (16 and 32 wide; the 16-wide one is the "
                    "smoke run, reused: a reused job joins the batch that asked for it): their "
                    "curves, and the batch's method x metric table, as `matforge results "
                    "--pivot` prints it "
                    "(each metric's mean ± spread, each cost's median, the best per column "
                    "marked).",
                )
            )
            browser.close()
    if args.out is None:
        (ROOT / "docs" / "compare-view.png").write_bytes(compare.read_bytes())
        (ROOT / "docs" / "screenshots.md").write_text(page_markdown(shots))
        print("  docs/compare-view.png, docs/screenshots.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
