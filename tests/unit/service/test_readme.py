"""The kinds reference of the docs site is generated from the registry and must be current,
and so must the typed documents' field tables of the artifacts page; the README keeps its
two commands."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test01_kinds_reference_is_current() -> None:
    spec = importlib.util.spec_from_file_location("kinds_table", REPO / "scripts/kinds_table.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = (REPO / "docs/reference/kinds.md").read_text(encoding="utf-8")
    assert mod.START in text and mod.END in text
    assert text == mod.page_with_table(text), (
        "docs/reference/kinds.md is stale: run `.venv/bin/python scripts/kinds_table.py --write`"
    )


def test05_artifact_fields_are_current() -> None:
    """docs/artifacts.md's field tables are the types' fields (``jobapi.documents``), so the
    page cannot drift from what ``put_json`` checks."""
    spec = importlib.util.spec_from_file_location("kinds_table", REPO / "scripts/kinds_table.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = (REPO / "docs/artifacts.md").read_text(encoding="utf-8")
    for typed in ("CurvesDocument", "ParetoDocument", "ScoreMetrics"):
        assert "<!-- fields:" in text and f".{typed} -->" in text, typed
    assert text == mod.artifacts_with_fields(text), (
        "docs/artifacts.md is stale: run `.venv/bin/python scripts/kinds_table.py --write`"
    )


def test02_readme_shows_the_two_commands() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert "make demo" in text and "make test" in text


def _tour() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    start = text.index("## A five-minute tour")
    return text[start : text.index("\n## ", start + 1)]


def test03_readme_tour_spec_is_valid() -> None:
    """The tour's ``gold.json`` is a valid spec with the name that its ``ls --name`` finds
    (the reference is :func:`service.specs.validate_spec`, what ``submit`` runs)."""
    import json
    import re

    from service.specs import validate_spec

    tour = _tour()
    body = re.search(r"cat > gold.json <<'JSON'\n(.*?)\nJSON\n", tour, re.S)
    assert body, "the tour writes gold.json with a heredoc"
    spec = json.loads(body.group(1))
    validate_spec(spec)
    names = re.findall(r"matforge ls --name (\S+)", tour)
    assert names and all(n in spec["name"] for n in names)


def test04_readme_tour_commands_exist() -> None:
    """Every ``matforge`` command line of the tour names a real subcommand, and every option
    it passes is one that subcommand's ``--help`` lists (the reference is the CLI itself)."""
    import re

    from typer.testing import CliRunner

    from service.cli.main import app

    lines = [ln.split("#", 1)[0].split() for ln in _tour().splitlines()]
    commands = [ln[1:] for ln in lines if ln[:1] == ["matforge"]]
    assert len(commands) >= 8
    runner = CliRunner()
    for words in commands:
        res = runner.invoke(app, [words[0], "--help"], env={"COLUMNS": "200"})
        assert res.exit_code == 0, (words, res.output)
        for opt in (w for w in words[1:] if w.startswith("--")):
            assert re.search(rf"{re.escape(opt)}\b", res.output), (words[0], opt)
