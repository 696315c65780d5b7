"""Batch files: parsing, validation (names, step refs, specs), running against a fake client,
and the result rows."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from jobapi.errors import SpecError
from jobapi.params import JOB_REF
from service import kinds
from service.cli.batch import (
    BatchError,
    load_batch,
    parse_batch,
    substitute_refs,
)
from service.cli.batch_run import run_batch
from service.cli.client import BadInput
from service.cli.results import headline, result_rows
from service.specs import JobSpec

KINDS = {"render", "score"}


def fake_validate(raw: Any) -> Any:
    """A stand-in for validate_spec: known kinds only, and every ``job:`` string must be a
    well-formed ref (the placeholders the batch parser substitutes must pass)."""
    if raw.get("kind") not in KINDS:
        raise SpecError([("kind", f"unknown job kind {raw.get('kind')!r}")])
    if set(raw) - set(JobSpec.model_fields):  # the real envelope's fields
        extra = sorted(set(raw) - set(JobSpec.model_fields))[0]
        raise SpecError([(extra, "Extra inputs are not permitted")])

    def walk(obj: Any, loc: str) -> None:
        if isinstance(obj, str) and obj.startswith("job:") and not JOB_REF.match(obj):
            raise SpecError([(loc, "bad ref")])
        if isinstance(obj, dict):
            for k, v in obj.items():
                walk(v, f"{loc}.{k}")

    walk(raw.get("params", {}), "params")

    class Valid:
        kind = raw["kind"]

    return Valid()


def render(seed: int = 0) -> dict[str, Any]:
    return {"kind": "render", "seed": seed, "params": {"scene": "sphere_env"}}


def score(reference: str, **candidates: str) -> dict[str, Any]:
    return {"kind": "score", "params": {"reference": reference, "candidates": candidates}}


def parse(doc: Any) -> Any:
    return parse_batch(doc, "b.yaml", validate=fake_validate)


def problems(doc: Any) -> str:
    with pytest.raises(BatchError) as info:
        parse(doc)
    return str(info.value)


# -- parsing ----------------------------------------------------------------------------------
def test01_valid_batch_with_refs() -> None:
    batch = parse(
        {
            "steps": [
                {"name": "gold", "spec": render(1)},
                {"name": "alu", "spec": render(2)},
                {"name": "score", "spec": score("step:gold/image.exr", a="step:alu/image.exr")},
            ]
        }
    )
    assert [s.name for s in batch.steps] == ["gold", "alu", "score"]
    assert [s.kind for s in batch.steps] == ["render", "render", "score"]
    refs = {(r.loc, r.step, r.artifact) for r in batch.steps[2].refs}
    assert refs == {
        ("params.reference", "gold", "image.exr"),
        ("params.candidates.a", "alu", "image.exr"),
    }
    # the stored spec keeps its step: refs; they are resolved only when running
    assert batch.steps[2].spec["params"]["reference"] == "step:gold/image.exr"


def test02_top_level_list_and_defaults() -> None:
    batch = parse([{"name": "a", "spec": render()}])
    assert len(batch.steps) == 1
    batch = parse(
        {
            "defaults": {"seed": 7, "force": True},
            "steps": [{"name": "a", "spec": {"kind": "render"}}, {"name": "b", "spec": render(3)}],
        }
    )
    assert batch.steps[0].spec["seed"] == 7 and batch.steps[0].spec["force"] is True
    assert batch.steps[1].spec["seed"] == 3  # the step's own value wins
    # issue 21: a time limit for every step
    batch = parse(
        {"defaults": {"timeout_seconds": 600}, "steps": [{"name": "a", "spec": render()}]}
    )
    assert batch.steps[0].spec["timeout_seconds"] == 600


def test03_forward_ref_is_rejected() -> None:
    msg = problems(
        {
            "steps": [
                {"name": "score", "spec": score("step:gold/image.exr")},
                {"name": "gold", "spec": render()},
            ]
        }
    )
    assert "b.yaml" in msg and "'score'" in msg and "params.reference" in msg
    assert "later step" in msg


def test04_unknown_step_and_self_ref() -> None:
    msg = problems(
        {
            "steps": [
                {"name": "gold", "spec": render()},
                {"name": "s", "spec": score("step:nope/image.exr", a="step:s/image.exr")},
            ]
        }
    )
    assert "'nope': no step of that name" in msg
    assert "refers to the step itself" in msg


def test05_malformed_step_ref() -> None:
    msg = problems(
        {
            "steps": [
                {"name": "gold", "spec": render()},
                {"name": "s", "spec": score("step:gold/")},
            ]
        }
    )
    assert "bad step reference 'step:gold/'" in msg and "params.reference" in msg
    # A bare step ref means the whole job, which score's reference does not accept.
    msg = problems(
        {
            "steps": [
                {"name": "gold", "spec": render()},
                {"name": "s", "spec": score("step:gold")},
            ]
        }
    )
    assert "params.reference" in msg and "bad step reference" not in msg


def test06_duplicate_and_bad_names() -> None:
    msg = problems(
        {
            "steps": [
                {"name": "a", "spec": render()},
                {"name": "a", "spec": render(1)},
                {"name": "has space", "spec": render(2)},
                {"spec": render(3)},
            ]
        }
    )
    assert "duplicate step name 'a' (first used by step #1)" in msg
    assert "step #3 'has space': name" in msg
    assert "step #4: name" in msg


def test07_spec_errors_name_step_and_field() -> None:
    msg = problems(
        {
            "steps": [
                {"name": "a", "spec": {"kind": "nope"}},
                {"name": "b", "spec": {**render(), "colour": 1}},
                {"name": "c", "spec": "not-a-mapping.yaml"},
                {"name": "d", "spec": render(), "extra": 1},
            ]
        }
    )
    assert "step #1 'a': kind: unknown job kind 'nope'" in msg
    assert "step #2 'b': colour:" in msg
    assert "step #3 'c': spec:" in msg and "no such file" in msg
    assert "step #4 'd': unknown field(s) extra" in msg


def test08_bad_top_level() -> None:
    assert "non-empty list of steps" in problems({"steps": []})
    assert "non-empty list of steps" in problems("just a string")
    assert "unknown top-level field(s) stepz" in problems({"stepz": []})
    assert "defaults" in problems(
        {"defaults": {"params": {}}, "steps": [{"name": "a", "spec": render()}]}
    )


def test09_load_batch_from_files(tmp_path: Path) -> None:
    (tmp_path / "gold.yaml").write_text("kind: render\nseed: 5\nparams: {scene: x}\n")
    f = tmp_path / "b.yaml"
    f.write_text(
        "steps:\n  - name: gold\n    spec: gold.yaml\n"
        "  - name: s\n    spec: {kind: score, params: {reference: step:gold/i.exr}}\n"
    )
    batch = load_batch(f, validate=fake_validate)
    assert batch.steps[0].spec["seed"] == 5
    with pytest.raises(BatchError, match="no such file"):
        load_batch(tmp_path / "missing.yaml", validate=fake_validate)
    (tmp_path / "bad.yaml").write_text("steps: [unclosed\n")
    with pytest.raises(BatchError, match="bad.yaml: not valid JSON or YAML"):
        load_batch(tmp_path / "bad.yaml", validate=fake_validate)


def test10_substitute_refs_copies() -> None:
    spec = score("step:a/x.exr", b="step:b/y.exr", c="sha256:" + "0" * 64)
    out = substitute_refs(spec, lambda r: r.replace("step:", "job:"))
    assert out["params"]["reference"] == "job:a/x.exr"
    assert out["params"]["candidates"]["c"] == "sha256:" + "0" * 64
    assert spec["params"]["reference"] == "step:a/x.exr"


def test11_real_validator_names_the_field() -> None:
    """With the real validate_spec (the built-in kinds), errors name the step and field."""
    with pytest.raises(BatchError) as info:
        parse_batch(
            {
                "steps": [
                    {"name": "a", "spec": {"kind": "no_such_kind"}},
                    {"name": "b", "spec": {"kind": "render", "bogus": 1}},
                ]
            },
            "x.yaml",
        )
    msg = str(info.value)
    assert "x.yaml: step #1 'a': kind: unknown job kind 'no_such_kind'" in msg
    assert "x.yaml: step #2 'b': bogus" in msg


# -- running ----------------------------------------------------------------------------------
#: A ``score`` metrics.json (``evaluators.score.document.ScoreMetrics``).
SCORE_METRICS = {
    "reference": "job:" + "0" * 32 + "/image.exr",
    "metrics": {"a": {"flip": 0.1, "psnr": 30.0}, "b": {"flip": 0.2}},
    "settings": {},
}


class FakeClient:
    """Finishes every job at once; ``fail`` names kinds whose jobs fail."""

    def __init__(self, fail: set[str] = frozenset(), artifacts: list[str] | None = None) -> None:
        self.fail = fail
        self.names = artifacts or ["image.exr", "preview.png"]
        self.submitted: list[dict[str, Any]] = []
        self.docs: dict[str, dict[str, Any]] = {}
        self.polls: list[str] = []

    def submit(self, spec: dict[str, Any]) -> dict[str, Any]:
        self.submitted.append(spec)
        job_id = f"{len(self.submitted):032x}"
        kind = spec["kind"]
        failed = kind in self.fail
        arts = (
            []
            if failed
            else [
                {"name": n, "digest": f"{len(self.submitted):064x}", "size": 1, "media_type": "x"}
                for n in self.names
            ]
        )
        if kind == "score" and not failed:
            arts.append(
                {
                    "name": "metrics.json",
                    "digest": "f" * 64,
                    "size": 1,
                    "media_type": "application/json",
                }
            )
        self.docs[job_id] = {
            "id": job_id,
            "kind": kind,
            "state": "failed" if failed else "succeeded",
            "progress": 1.0,
            "message": "",
            "error": "boom" if failed else None,
            "artifacts": arts,
            "timings": {"run_seconds": 0.25},
        }
        return {"id": job_id, "state": "queued"}

    def submit_created(self, spec: dict[str, Any]) -> tuple[dict[str, Any], bool]:
        return self.submit(spec), True

    def get(self, job_id: str) -> dict[str, Any]:
        self.polls.append(job_id)
        return self.docs[job_id]

    def read_bytes(self, digest: str) -> bytes:
        return json.dumps(SCORE_METRICS).encode()

    def summary(self, job_id: str) -> dict[str, Any] | None:
        """What the server's ``GET /api/jobs/{id}/summary`` returns: the kind's hook."""
        doc = self.docs[job_id]
        names = {a["name"] for a in doc["artifacts"]}
        kind = kinds.get_kind(doc["kind"])
        if kind.summary is None or doc["state"] != "succeeded":
            return None
        table = kind.summary(lambda name: SCORE_METRICS if name in names else None)
        return table.document() if table is not None else None


def quiet() -> Console:
    return Console(file=io.StringIO())


def three_steps() -> Any:
    return parse(
        {
            "steps": [
                {"name": "gold", "spec": render(1)},
                {"name": "alu", "spec": render(2)},
                {
                    "name": "score",
                    "spec": score(
                        "step:gold/image.exr", a="step:alu/image.exr", b="step:alu/preview.png"
                    ),
                },
            ]
        }
    )


def test20_run_resolves_refs_and_flattens_metrics(tmp_path: Path) -> None:
    client = FakeClient()
    outcome = run_batch(three_steps(), client, quiet(), poll_seconds=0.01)  # type: ignore[arg-type]
    assert outcome.exit_code == 0
    assert [r.state for r in outcome.results] == ["succeeded"] * 3
    params = client.submitted[2]["params"]
    assert params["reference"] == f"job:{1:032x}/image.exr"
    labels = {spec["batch"] for spec in client.submitted}  # one batch run, one label
    assert len(labels) == 1 and labels.pop().startswith("b.yaml ")
    assert params["candidates"] == {
        "a": f"job:{2:032x}/image.exr",
        "b": f"job:{2:032x}/preview.png",
    }
    columns, rows = result_rows(outcome.results)
    assert columns[-3:] == ["a.flip", "a.psnr", "b.flip"]
    assert rows[2]["a.psnr"] == 30.0 and rows[0]["a.psnr"] is None
    assert rows[1]["seconds"] == 0.25

    # the terminal's one line per step: the score step's headline (its first column)
    (score,) = [r for r in outcome.results if r.step == "score"]
    assert headline(score.table).startswith("flip: a 0.1") and headline(None) == ""
    assert len(headline(score.table, width=12)) == 12


def test21_failed_step_stops_the_batch() -> None:
    batch = parse(
        {
            "steps": [
                {"name": "gold", "spec": render(1)},
                {"name": "s", "spec": score("step:gold/image.exr")},
                {"name": "after", "spec": render(3)},
            ]
        }
    )
    client = FakeClient(fail={"score"})
    outcome = run_batch(batch, client, quiet(), poll_seconds=0.01)  # type: ignore[arg-type]
    assert outcome.exit_code == 1
    assert [r.state for r in outcome.results] == ["succeeded", "failed", "skipped"]
    assert outcome.results[1].error == "boom"
    assert len(client.submitted) == 2


def test22_missing_artifact_is_a_clear_error() -> None:
    batch = parse(
        {
            "steps": [
                {"name": "gold", "spec": render(1)},
                {"name": "s", "spec": score("step:gold/nope.exr")},
            ]
        }
    )
    client = FakeClient()
    outcome = run_batch(batch, client, quiet(), poll_seconds=0.01)  # type: ignore[arg-type]
    assert outcome.exit_code == BadInput.exit_code == 2
    assert outcome.results[1].state == "error"
    err = outcome.results[1].error or ""
    assert "step:gold/nope.exr" in err and "has no artifact 'nope.exr'" in err
    assert "image.exr" in err  # lists what the step does have
    assert len(client.submitted) == 1


def test23_continue_on_error_skips_only_the_dependents() -> None:
    steps = {
        "steps": [
            {"name": "gold", "spec": render(1)},
            {"name": "s", "spec": score("step:gold/image.exr")},
            {"name": "needs_s", "spec": score("step:s/metrics.json")},
            {"name": "after", "spec": render(3)},
        ]
    }
    client = FakeClient(fail={"score"})
    outcome = run_batch(parse(steps), client, quiet(), poll_seconds=0.01, continue_on_error=True)  # type: ignore[arg-type]
    assert outcome.exit_code == 1
    assert [r.state for r in outcome.results] == ["succeeded", "failed", "skipped", "succeeded"]
    assert "needs step 's'" in (outcome.results[2].error or "")
    assert [spec["kind"] for spec in client.submitted] == ["render", "score", "render"]
    # without the flag, the batch stops at the failure
    stopped = run_batch(parse(steps), FakeClient(fail={"score"}), quiet(), poll_seconds=0.01)  # type: ignore[arg-type]
    assert [r.state for r in stopped.results] == ["succeeded", "failed", "skipped", "skipped"]


class SlowClient(FakeClient):
    """Each job reports ``running`` on its first poll; ``log`` records submits and polls."""

    def __init__(self) -> None:
        super().__init__()
        self.log: list[str] = []

    def submit(self, spec: dict[str, Any]) -> dict[str, Any]:
        doc = super().submit(spec)
        self.log.append(f"submit {spec['kind']}")
        return doc

    def get(self, job_id: str) -> dict[str, Any]:
        self.log.append("poll")
        first = job_id not in self.polls
        doc = super().get(job_id)
        return {**doc, "state": "running", "progress": 0.5} if first else doc


def test24_parallel_runs_independent_steps_at_once() -> None:
    client = SlowClient()
    outcome = run_batch(three_steps(), client, quiet(), poll_seconds=0.01, parallel=2)  # type: ignore[arg-type]
    assert [r.state for r in outcome.results] == ["succeeded"] * 3
    # gold and alu are both submitted before any poll; score only after both finished
    assert client.log[:3] == ["submit render", "submit render", "poll"]
    assert client.log.index("submit score") > 4
    serial = SlowClient()
    run_batch(three_steps(), serial, quiet(), poll_seconds=0.01)  # type: ignore[arg-type]
    assert serial.log[:4] == ["submit render", "poll", "poll", "submit render"]


def test_result_tables_flatten_to_label_column_metrics() -> None:
    """The batch's metric columns are the numeric cells of the kinds' result tables (bools,
    text and missing values left out), through the tables' JSON form."""
    from evaluators.score.kind import summarize as score_summary
    from jobapi.results import ResultTable
    from models.brdf.kind import summarize as brdf_summary
    from tests.helpers.job_documents import brdf_metrics, brdf_scores

    doc = {"reference": "sha256:00", "metrics": {"a": {"flip": 0.1, "psnr": None}}, "settings": {}}
    score = score_summary(lambda name: doc)
    assert score is not None
    assert ResultTable.from_document(score.document()).flat() == {"a.flip": 0.1}
    gold = brdf_scores("gold", "metal", smape=0.2, smape_floor=0.1, mae=0.5)
    doc = brdf_metrics([gold], smape=0.2, mae=0.5)
    brdf = brdf_summary(lambda name: doc if name == "metrics.json" else None)
    assert brdf is not None
    assert brdf.flat() == {
        "gold.smape": 0.2,
        "gold.smape_floor": 0.1,
        "gold.mae": 0.5,
        "mean.smape": 0.2,
        "mean.mae": 0.5,
    }


def test_bare_step_ref_means_the_whole_job() -> None:
    from service.cli.batch import _placeholder
    from service.specs import STEP_REF

    m = STEP_REF.match("step:tables")
    assert m is not None and m["step"] == "tables" and m["name"] is None
    assert _placeholder("step:tables") == "job:" + _placeholder("step:t/x")[4:36]
    assert _placeholder("step:t/x").endswith("/x")


def test_short_job_refs_pass_local_validation() -> None:
    """A step may name an existing job by a unique prefix of its id (the server resolves
    it on submission); the batch's own check sees a well-formed ref."""
    from service.cli.batch import pad_short_job_refs

    batch = parse({"steps": [{"name": "s", "spec": score("job:3f2a9c/image.exr")}]})
    assert batch.steps[0].spec["params"]["reference"] == "job:3f2a9c/image.exr"  # kept as written
    padded = pad_short_job_refs({"a": ["job:3f2a9c/x.exr", "job:" + "1" * 32 + "/y"]})
    assert padded == {"a": ["job:3f2a9c" + "0" * 26 + "/x.exr", "job:" + "1" * 32 + "/y"]}


def test30_a_step_without_a_spec_name_takes_the_step_name() -> None:
    """Two renders of one batch show as ``gold`` and ``alu`` in ``ls``, not both ``render``;
    a spec's own name is kept."""
    batch = three_steps()
    batch.steps[1].spec["name"] = "aluminium sphere"
    client = FakeClient()
    run_batch(batch, client, quiet(), poll_seconds=0.01)  # type: ignore[arg-type]
    assert [s["name"] for s in client.submitted] == ["gold", "aluminium sphere", "score"]


def test31_vars_are_filled_from_the_command_line_or_their_defaults() -> None:
    """``vars`` declare a recipe's parameters; ``var:<name>`` strings take the given value
    (``--var``) or the default; a missing value, an unknown ``var:`` and an undeclared
    ``--var`` are errors naming it."""
    doc = {
        "vars": {"model": None, "spp": "step:a/image.exr"},
        "steps": [
            {"name": "a", "spec": {"kind": "render", "params": {"scene": "x"}}},
            {"name": "b", "spec": {"kind": "score", "params": {
                "reference": "var:spp",
                "candidates": {"m": {"external": {"model": "var:model"}}}}}},
        ],
    }  # fmt: skip
    batch = parse_batch(doc, validate=fake_validate, variables={"model": "sha256:" + "a" * 64})
    params = batch.steps[1].spec["params"]
    assert params["candidates"]["m"]["external"]["model"] == "sha256:" + "a" * 64
    assert params["reference"] == "step:a/image.exr"  # a default may be a step ref
    assert [r.step for r in batch.steps[1].refs] == ["a"]
    with pytest.raises(BatchError, match=r"vars.model: no value; give --var model=VALUE"):
        parse_batch(doc, validate=fake_validate)
    with pytest.raises(BatchError, match=r"--var nope: not a variable of this batch"):
        parse_batch(doc, validate=fake_validate, variables={"model": "x", "nope": "y"})
    bad = {**doc, "vars": {"model": "x"}}
    with pytest.raises(BatchError, match=r"var:spp: no variable 'spp'"):
        parse_batch(bad, validate=fake_validate)


def test32_parse_vars() -> None:
    """``--var NAME=VALUE`` (``batch`` and ``results`` share it): the value may hold ``=``;
    an item without ``=`` or without a name is refused, naming it."""
    from service.cli.batch import BatchError, parse_vars

    assert parse_vars(["model=sha256:ab", "x=a=b"]) == {"model": "sha256:ab", "x": "a=b"}
    for bad in ("model", "=v"):
        with pytest.raises(BatchError, match=f"--var {bad}: expected NAME=VALUE"):
            parse_vars([bad])


def test33_integer_vars() -> None:
    """A variable with an integer default is an integer (a spec's size field): ``--var``
    gives it as text, the spec gets the number; a non-integer value, a float or a boolean
    default is refused, naming it."""
    doc = {
        "vars": {"res": 32, "name": "x"},
        "steps": [{"name": "a", "spec": {"kind": "render", "params": {
            "scene": "var:name", "spp": "var:res"}}}],
    }  # fmt: skip
    params = parse_batch(doc, validate=fake_validate).steps[0].spec["params"]
    assert params == {"scene": "x", "spp": 32}
    given = parse_batch(doc, validate=fake_validate, variables={"res": "16", "name": "7"})
    assert given.steps[0].spec["params"] == {"scene": "7", "spp": 16}  # a string var stays text
    with pytest.raises(BatchError, match=r"--var res=1.5: res is an integer variable"):
        parse_batch(doc, validate=fake_validate, variables={"res": "1.5"})
    for default in (1.5, True):
        with pytest.raises(BatchError, match=r"vars: must map names to string or integer"):
            parse_batch({**doc, "vars": {"res": default}}, validate=fake_validate)
