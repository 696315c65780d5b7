"""Every registered job kind runs its own tiny smoke params end to end through the registry
(in the style of nerfstudio's test_train.py): validation, queue, runner, artifacts, manifest,
and its summary hook on the real artifacts.

A kind whose inputs are other jobs (``score``, ``train.*``, ``report.*``) names them in its
smoke params as ``step:<kind>`` (the whole job) or ``step:<kind>/<artifact>``: the smoke run
of that kind, made first (once per module) and substituted as ``job:<id>[/<artifact>]``.
A kind that cannot have smoke params must be listed in :data:`NO_SMOKE` with the reason.

Each typed document a kind declares (:attr:`jobapi.kinds.Kind.documents`) is checked when
the smoke job writes it; here the real document also reads typed, and the same document with
its first required field removed, or of the wrong type, is refused naming the file and field.

Same spec, same bytes (CONTRACT.md, "Job spec"): each smoke spec is run a second time
(``force``, the same resolved spec, so the same input jobs) and every artifact's digest must
equal the first run's, except those its kind declares as timings
(:attr:`jobapi.kinds.Kind.timing_artifacts`); timings belong in the manifest.
"""

from __future__ import annotations

import fnmatch
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from jobapi.documents import DocumentError, check_typed, document_fields, read_typed
from jobapi.kinds import Kind
from jobapi.metric_names import declared
from jobapi.row_sources import job_rows
from service import kinds
from service.cli.batch import substitute_refs
from service.settings import Settings
from service.specs import STEP_REF
from service.submission import run_in_process
from service.summaries import job_summary
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore

KINDS = sorted(kinds.all_kinds().values(), key=lambda k: k.name)
#: Kinds without smoke params, each with the reason.
NO_SMOKE: dict[str, str] = {
    "import.btf": "its input is a user's uploaded .btf.zip, which no kind writes; "
    "tests/integration/test_import_btf.py builds one from generate.btf's slices",
}


class SmokeRuns:
    """The smoke job of each kind, run on demand with its dependencies first."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.done: dict[str, Job] = {}
        #: The spec each smoke job ran, its ``step:`` refs resolved.
        self.specs: dict[str, dict[str, Any]] = {}

    def job(self, name: str, chain: tuple[str, ...] = ()) -> Job:
        if name in chain:
            raise AssertionError(f"smoke params form a cycle: {' -> '.join((*chain, name))}")
        if name not in self.done:
            kind = kinds.get_kind(name)

            def resolve(ref: str) -> str:
                m = STEP_REF.match(ref)
                assert m is not None
                dep = self.job(m["step"], (*chain, name))
                assert dep.state == "succeeded", f"{name} needs {m['step']}: {dep.error}"
                return f"job:{dep.id}" if m["name"] is None else f"job:{dep.id}/{m['name']}"

            params: dict[str, Any] = substitute_refs(kind.smoke, resolve)
            spec = {"kind": name, "seed": 0, "params": params}
            self.specs[name] = spec
            self.done[name] = run_in_process(spec, self.settings)
        return self.done[name]


@pytest.fixture(scope="module")
def smoke(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SmokeRuns]:
    data = Path(tmp_path_factory.mktemp("smoke")) / "data"
    yield SmokeRuns(Settings.from_env({}).with_(data_dir=data, pool_processes=1))


def test00_every_kind_documents_itself() -> None:
    for kind in KINDS:
        assert kind.description, kind.name
        schema = kind.params.model_json_schema()
        assert schema.get("additionalProperties") is False, f"{kind.name} params are not strict"
        for name, prop in schema.get("properties", {}).items():
            assert prop.get("description"), f"{kind.name}.params.{name} has no description"


def test00_every_kind_has_smoke_params_or_a_reason() -> None:
    for kind in KINDS:
        assert bool(kind.smoke) != (kind.name in NO_SMOKE), kind.name
    assert set(NO_SMOKE) <= {k.name for k in KINDS}


@pytest.mark.parametrize("kind", [k for k in KINDS if k.smoke], ids=lambda k: k.name)
def test01_smoke(kind: Kind, smoke: SmokeRuns) -> None:
    job = smoke.job(kind.name)
    assert job.state == "succeeded", job.error
    names = [a.name for a in job.artifacts]
    for pattern in kind.artifacts:  # "<label>" placeholders stand for any name
        glob = re.sub(r"<[^>]+>", "*", pattern)
        assert any(fnmatch.fnmatch(n, glob) for n in names), (pattern, names)
    store = ArtifactStore(smoke.settings.store_dir)
    manifest = json.loads(store.read(job.manifest_digest))
    assert [a["name"] for a in manifest["artifacts"]] == sorted(names)
    for art in job.artifacts:
        assert store.verify(art.digest)
    # The summary hook turns the real artifacts into a table with at least one value.
    if kind.summary is not None:
        table = job_summary(job, store)
        assert table is not None, f"{kind.name}: the summary hook found no table"
        assert table["labels"] and table["names"], table
        assert all(set(row) <= set(table["names"]) for row in table["rows"].values())
    # Every metric of its result rows is one it declares (what `metric.<name>` columns,
    # filters and `--metric` accept): a name it does not declare would be refused there.
    if kind.rows is not None:
        rows = job_rows(job, JobStore(smoke.settings.db_path), store)
        undeclared = {r.metric for r in rows if not declared(kind.metrics, r.metric)}
        assert not undeclared, f"{kind.name}: rows of undeclared metrics {sorted(undeclared)}"


DOCUMENTS = [(k, name) for k in KINDS if k.smoke for name in k.documents]


@pytest.mark.parametrize(("kind", "name"), DOCUMENTS, ids=lambda x: getattr(x, "name", x))
def test01_typed_documents_of_a_real_job(kind: Kind, name: str, smoke: SmokeRuns) -> None:
    """The oracle for "valid" is the job itself (``put_json`` checked the document against
    its type); the malformed copies each break one field the type requires, so the type
    must refuse them and name that field."""
    job = smoke.job(kind.name)
    assert job.state == "succeeded", job.error
    typed = kind.documents[name]
    (art,) = [a for a in job.artifacts if a.name == name]
    doc = json.loads(ArtifactStore(smoke.settings.store_dir).read(art.digest))
    check_typed(name, doc, typed)
    assert read_typed(doc, typed) is not None, (kind.name, name)
    field = next(f for f, _, required, _ in document_fields(typed) if required and "." not in f)
    missing = {k: v for k, v in doc.items() if k != field}
    mistyped = {**doc, field: [True]}  # no field of any document is a list of booleans
    for bad in (missing, mistyped):
        with pytest.raises(DocumentError, match=rf"^{re.escape(name)}: {re.escape(field)}\b"):
            check_typed(name, bad, typed)
        assert read_typed(bad, typed) is None


@pytest.mark.slow
@pytest.mark.parametrize("kind", [k for k in KINDS if k.smoke], ids=lambda k: k.name)
def test02_same_spec_same_bytes(kind: Kind, smoke: SmokeRuns) -> None:
    """The oracle is the first run itself: a forced second run of the same spec (same
    params, seed and input jobs) must store the same bytes for every artifact but the kind's
    declared timing artifacts. A timing written into any other artifact fails here."""
    first = smoke.job(kind.name)
    assert first.state == "succeeded", first.error
    again = run_in_process({**smoke.specs[kind.name], "force": True}, smoke.settings)
    assert again.state == "succeeded", again.error
    assert again.id != first.id, "force must run the spec again, not return the first job"
    params = kind.params.model_validate(smoke.specs[kind.name]["params"])
    before = {a.name: a.digest for a in first.artifacts}
    after = {a.name: a.digest for a in again.artifacts}
    assert sorted(before) == sorted(after), kind.name
    timings = {n for n in before if kind.is_timing_artifact(n, params)}
    differ = sorted(n for n in before if n not in timings and before[n] != after[n])
    assert not differ, (
        f"{kind.name}: same spec, other bytes in {differ} (a timing belongs in the manifest, "
        "ctx.measure, or in Kind.timing_artifacts if it is the kind's product)"
    )
