"""Kind knowledge lives with its kind (DESIGN.md, "Kind knowledge lives with its kind"; issue
28 §2): the shared modules never name a kind, and a kind added from outside is read by the
report code through what it declares (:class:`jobapi.reports.ReportFacts`), touching nothing
else.

The oracle of the scan is the registry itself: every registered kind's name, looked for as
a whole string literal (``ast.Constant``) in the shared modules. A kind module may name
itself in its own ``Kind(name=...)``; anything else needs an entry in :data:`ALLOWED` with
the reason.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from evaluators.report import claims, stability
from evaluators.report.fronts import check_claim
from jobapi import kinds as jobapi_kinds
from jobapi.kinds import Kind, registered
from jobapi.reports import CheckClaim, ReportFacts, phase_loss
from jobapi.rows import ResultRow
from service import kinds

ROOT = Path(__file__).resolve().parents[3]
#: The modules every kind shares: they must ask the registry, never name a kind. (Not
#: ``matforge/datasets/``: one reader module per dataset family, each naming its kinds.)
SHARED = (
    "jobapi/*.py",
    "service/**/*.py",
    "matforge/*.py",
    "evaluators/*.py",
    "evaluators/report/*.py",
    "evaluators/metrics/*.py",
    "generators/*.py",
    "models/*.py",
    "storage/**/*.py",
    "materials/*.py",
)
#: ``(file, kind name) -> why`` it may appear there as a literal.
ALLOWED: dict[tuple[str, str], str] = {
    ("evaluators/report/stability.py", "score"): "report.stability's second input kind by "
    "contract: score jobs' rows are read as render-level families (SCORE_KIND, named once)",
    ("evaluators/report/select_scene.py", "render"): "a shard label (progress 'renders: "
    "k/n'), not the render kind",
}


def _shared_files() -> list[Path]:
    return sorted({p for pattern in SHARED for p in ROOT.glob(pattern)})


def _own_names(tree: ast.AST) -> set[int]:
    """``id``s of the ``name=`` constants of ``Kind(...)`` calls: a kind naming itself."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Kind":
            out |= {id(k.value) for k in node.keywords if k.arg == "name"}
    return out


def _literals(path: Path, names: set[str]) -> Iterator[tuple[int, str]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    own = _own_names(tree)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and node.value in names
            and id(node) not in own
        ):
            yield node.lineno, node.value


def test01_shared_modules_name_no_kind() -> None:
    kinds.load_builtin()
    names = set(registered())
    assert {"train.brdf", "score", "generate.glint"} <= names  # the scan sees the kinds
    files = _shared_files()
    assert ROOT / "evaluators/report/stability.py" in files
    found = [
        f"{p.relative_to(ROOT)}:{line}: {name!r}"
        for p in files
        for line, name in _literals(p, names)
        if (str(p.relative_to(ROOT)), name) not in ALLOWED
    ]
    assert not found, (
        "shared modules name kinds; declare the knowledge on the kind (jobapi.reports."
        "ReportFacts, Kind.rows, ...) and ask the registry:\n" + "\n".join(found)
    )


def test02_the_allowlist_is_still_needed() -> None:
    kinds.load_builtin()
    names = set(registered())
    for (file, name), why in ALLOWED.items():
        assert why
        assert any(n == name for _, n in _literals(ROOT / file, names)), (file, name)


def test03_the_scan_catches_a_kind_name(tmp_path: Path) -> None:
    path = tmp_path / "probe.py"
    path.write_text('if job.kind == "train.brdf":\n    pass\nKind(name="train.brdf")\n')
    assert list(_literals(path, {"train.brdf"})) == [(1, "train.brdf")]


def test04_the_training_kinds_declare_what_the_reports_read() -> None:
    """The facts each training kind declares are those report.stability had by name before
    they moved (SMAPE; the fabric network's RGB relative error; L1, with failure cases by
    relative L1; the loss keys)."""
    kinds.load_builtin()
    facts = {n: k.report for n, k in registered().items() if k.report is not None}
    assert set(facts) == {"train.brdf", "train.fabric", "train.btf"}
    got = {n: (f.metric, f.candidate, f.families_by, f.loss_key) for n, f in facts.items()}
    assert got == {
        "train.brdf": ("brdf.smape", None, "brdf.smape", "loss"),
        "train.fabric": ("rgb.rel", "network", "rgb.rel", "loss"),
        "train.btf": ("l1", None, "relative_l1", "train_loss"),
    }
    assert facts["train.brdf"].checks is not None
    assert [n for n, f in facts.items() if f.claims is not None] == ["train.brdf", "train.fabric"]


class _ToyParams(BaseModel):
    pass


def _toy_claims(rows: Sequence[ResultRow], check: CheckClaim) -> list[dict[str, Any]]:
    mine = [r for r in rows if r.kind == "train.toy"]
    return [check(mine, {"a": "big", "b": "small", "metric": "toy_err", "claim": "big wins"})]


def _row(candidate: str, value: float, family: str | None = None) -> ResultRow:
    return ResultRow(
        job="a" * 32,
        kind="train.toy",
        metric="toy_err",
        value=value,
        candidate=candidate,
        family=family,
        lower_is_better=True,
    )


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch) -> Kind:
    """A training kind added from outside the tree: only its own declaration."""
    kinds.load_builtin()
    kind = Kind(
        name="train.toy",
        params=_ToyParams,
        runner=lambda p, ctx: None,
        description="test-only training kind",
        rows=lambda src: [],
        report=ReportFacts(metric="toy_err", loss_key="toy_loss", claims=_toy_claims),
    )
    monkeypatch.setitem(jobapi_kinds._KINDS, kind.name, kind)
    return kind


def test05_a_new_kind_is_read_through_its_declaration(toy: Kind) -> None:
    rows = [
        _row("big", 0.1),
        _row("small", 0.4),
        _row("big", 0.3, family="hard"),
        _row("big", 0.05, family="easy"),
    ]
    assert "train.toy" in stability.trained_kinds()
    assert stability.headline("train.toy", rows) == ("toy_err", 0.1, "big")
    cells = {c["family"]: c for c in stability.families(rows) if c["kind"] == "train.toy"}
    assert cells["hard"]["ratio"] == pytest.approx(3.0)
    assert cells["easy"]["ratio"] == pytest.approx(0.5)
    curves = {"step": [1, 2, 3], "toy_loss": [3.0, 2.0, 1.0]}
    assert stability.loss_curve("train.toy", curves) == [3.0, 2.0, 1.0]
    (claim,) = [c for c in claims.family_claims(rows) if c["claim"] == "big wins"]
    assert claim["holds"] is True


def test06_family_claims_are_each_kinds_own_in_registry_order() -> None:
    from models.brdf.claims import brdf_claims
    from models.fabric.claims import fabric_claims

    kinds.load_builtin()
    rows = [
        ResultRow(job="b" * 32, kind="train.brdf", metric="brdf.smape", value=v, candidate=c)
        for c, v in (("hybrid 16x3", 0.1), ("analytic", 0.2))
    ] + [
        ResultRow(
            job="c" * 32, kind="score", metric="image.flip", value=v, candidate=c, dataset="s"
        )
        for c, v in (("net16", 0.1), ("mc_eq", 0.2))
    ]
    expect = brdf_claims(rows, check_claim) + fabric_claims(rows, check_claim)
    assert len(expect) == 2
    assert claims.family_claims(rows) == expect


def test07_phase_loss_of_the_one_schema() -> None:
    doc: Mapping[str, Any] = {
        "step": [1, 2, 3],
        "loss": [3.0, 2.0, 1.0],
        "phases": [
            {"name": "train", "first_step": 1, "last_step": 2},
            {"name": "heldout", "first_step": 3, "last_step": 3},
        ],
    }
    assert phase_loss(dict(doc)) == [3.0, 2.0]
    # Not of the schema (a step after the last phase): no loss rather than a guess.
    assert phase_loss({**doc, "phases": doc["phases"][:1]}) == []
    assert phase_loss(dict(doc), "other") == []
    assert phase_loss(None) == [] and phase_loss([1.0]) == []
