"""Every column, filter and metric example the docs give is one that works: extracted from
the markdown (and the dashboard's placeholders and the CLI's and API's help), each is
parsed as ``matforge ls --column/--filter``, ``?columns=``/``?filter=`` and ``--metric``
parse it (:mod:`service.job_columns`, :func:`service.results.check_row_filter`), so an
example naming a metric no kind writes (``metric.smape_mean`` once was one) fails here, and
so does a future doc edit that adds one."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from service.job_columns import parse_filters, parse_keys
from service.results import RowFilter, check_row_filter

ROOT = Path(__file__).resolve().parents[3]
#: Where examples are written: the docs, the README, the dashboard's boxes, the help texts.
SOURCES = sorted(
    [
        *ROOT.glob("docs/**/*.md"),
        ROOT / "README.md",
        ROOT / "service/dashboard/templates/index.html",
        ROOT / "service/dashboard/static/js/jobs.js",
        ROOT / "service/cli/listing.py",
        ROOT / "service/job_list.py",
    ]
)
#: A column key or filter as written in an example.
EXAMPLE = re.compile(r"^(params|metric)\.[A-Za-z0-9_\-]+(\.[A-Za-z0-9_\-]+)*((<=|>=|!=|=|<|>).+)?$")
#: Tokens that are file or code names, not examples (``params.py``).
NOT_EXAMPLES = re.compile(r"\.(py|md|json)$|\(")
_OP = re.compile(r"<=|>=|!=|=|<|>")
#: Examples the docs give of what is refused (docs/usage.md, "One unit per column"): each
#: must be refused.
REFUSED = {"metric.mae"}


def spans(text: str) -> list[str]:
    """The code of ``text``: markdown and docstring backticks, quoted help and attribute
    strings."""
    found = re.findall(r"`+([^`]+?)`+", text)
    found += re.findall(r'placeholder="([^"]+)"', text)
    found += re.findall(r"'((?:metric|params)\.[^']+)'", text)
    found += re.findall(r"\b(?:e\.g\.|such as)\s+((?:metric|params)\.[^\s,;)]+)", text)
    found += re.findall(r"\?(columns=[^\s)`]+)", text)
    return found


def examples(text: str) -> list[str]:
    """The column keys and filters among ``text``'s code."""
    out: list[str] = []
    for span in spans(text.replace("&lt;", "<").replace("&gt;", ">")):
        for piece in re.split(r"[&\s,]+", span):
            piece = re.sub(r"^\??(columns|filter)=", "", piece.strip("'\".;:"))
            if EXAMPLE.match(piece) and not NOT_EXAMPLES.search(piece):
                out.append(piece)
    return out


def metric_options(text: str) -> list[str]:
    """The values of ``--metric NAME`` and ``metric=NAME`` in ``text``'s code (not the
    placeholders, ``--metric M``)."""
    out = []
    for span in spans(text):
        out += re.findall(r"--metric[ =]([A-Za-z][A-Za-z0-9_.\-]*)", span)
        out += re.findall(r"[?&]metric=([A-Za-z][A-Za-z0-9_.\-]*)", span)
    return [m for m in out if not m.isupper()]


ALL = [(p.relative_to(ROOT).as_posix(), e) for p in SOURCES for e in examples(p.read_text())]


def test00_the_docs_give_examples() -> None:
    """The extraction finds the examples (a change of their form must not make this test
    vacuous): the usage guide's and the dashboard's."""
    where = {src for src, _ in ALL}
    assert {"docs/usage.md", "service/dashboard/templates/index.html"} <= where, where
    assert any(e.startswith("metric.") and _OP.search(e) for _, e in ALL)


@pytest.mark.parametrize(("source", "example"), ALL, ids=[f"{s}:{e}" for s, e in ALL])
def test01_every_example_parses(source: str, example: str) -> None:
    if example in REFUSED:
        from jobapi.errors import SpecError

        with pytest.raises(SpecError):
            parse_keys([example], source)
        return
    if _OP.search(example.split(".", 1)[1]):
        parse_filters([example], source)
    else:
        parse_keys([example], source)


def test02_metric_options_in_the_docs_are_metrics() -> None:
    names = [(p.name, m) for p in SOURCES for m in metric_options(p.read_text())]
    assert ("usage.md", "brdf.smape") in names  # the extraction finds the guide's
    for source, name in names:
        check_row_filter(RowFilter(metric=(name,)), {"metric": source})


def test03_a_wrong_example_would_fail() -> None:
    """The check is the one that refuses: the old example, and a misspelt param."""
    from jobapi.errors import SpecError

    with pytest.raises(SpecError, match="did you mean 'metric.brdf.smape'"):
        parse_filters(examples("`metric.smape_mean<0.1`"), "doc")
    with pytest.raises(SpecError, match="did you mean 'params.model'"):
        parse_keys(examples("`?columns=params.modle`"), "doc")
