"""Parameter and metric columns of the job list, and filters on them.

A *column key* names one value of a job:

- ``params.<path>``: a value of the job's spec params, ``.``-separated at any depth
  (``params.model``, ``params.material.mitsuba.alpha``); its first name is a param of some
  kind (else refused, with the closest ones);
- ``metric.<name>``: the mean of the job's result rows for that metric
  (:mod:`jobapi.rows`; e.g. ``metric.brdf.smape``, ``metric.image.psnr``), over its
  candidates, materials and scenes, and of its ``test`` rows where it has some (held-out
  materials: the test error, not the training one); a job without such rows has none. The
  name is a metric some kind declares (:attr:`jobapi.kinds.Kind.metrics`) or an old name
  that stands for one (``metric.smape`` is ``metric.brdf.smape``:
  :mod:`jobapi.metric_names`); any other is refused with the closest known names, and so
  is ``metric.mae``, which would mix a BRDF-space and an image MAE in one column.

A *filter* is ``<key><op><value>`` with ``op`` one of ``=``, ``!=``, ``<``, ``<=``, ``>``,
``>=``: ``params.model=hybrid``, ``metric.brdf.smape<0.1``. ``=``/``!=`` compare as numbers
when both sides are numbers, else as text (``true``/``false``/``null`` match JSON values
as written); the order comparisons need numbers. A job without the value never passes a
filter (``!=`` included: "a job whose model is not hybrid" has a model).

``GET /api/jobs?columns=&filter=``, ``matforge ls --column --filter`` and the dashboard's
job list come through here.
"""

from __future__ import annotations

import difflib
import json
import math
import operator
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from jobapi.errors import SpecError
from jobapi.kinds import declared_metrics
from jobapi.metric_names import one_column, unknown_metric

#: A column key: ``params.`` or ``metric.`` and a dotted path of names.
KEY = re.compile(r"^(params|metric)\.[A-Za-z0-9_\-]+(\.[A-Za-z0-9_\-]+)*$")
_KEY_BODY = r"(?:params|metric)\.[A-Za-z0-9_\-]+(?:\.[A-Za-z0-9_\-]+)*"
#: A number an order filter (``<``, ``<=``, ``>``, ``>=``) compares with.
_NUMBER = r"[+\-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+\-]?[0-9]+)?"
_FILTER_BODY = (
    rf" *({_KEY_BODY}) *(?:(=|!=) *([^ ][\s\S]*)|(<=|>=|<|>) *({_NUMBER}) *)"
)  # fmt: skip
#: What a filter is, as the OpenAPI document states it (``GET /api/jobs?filter=``): the one
#: rule :func:`parse_filters` applies, so a filter the schema allows is never refused. ECMA
#: and Python read it alike (no ``.``, ``\d`` or ``\w``; matched whole).
FILTER_PATTERN = f"^{_FILTER_BODY}$"
_FILTER = re.compile(_FILTER_BODY)
#: A looser reading of a filter that fails :data:`FILTER_PATTERN`, to say what is wrong.
_LOOSE = re.compile(r"^\s*([A-Za-z0-9_.\-]+)\s*(<=|>=|!=|=|<|>)\s*(.*?)\s*$", re.DOTALL)
_ORDER: dict[str, Callable[[float, float], bool]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
}
#: Most columns or filters one list takes.
MAX_KEYS = 16


def check_key(key: str, where: str) -> str:
    """``key`` if it is a column key, else :class:`SpecError` naming ``where``: not of the
    form, or a ``metric.`` key whose name no kind declares (with did-you-mean), or an old
    name of metrics in two spaces (:func:`jobapi.metric_names.unknown_metric`)."""
    if not KEY.match(key):
        raise SpecError(
            [
                (
                    where,
                    f"{key!r} is not a column: use params.<name>[.<name>...] or "
                    "metric.<name> (e.g. params.model, metric.brdf.smape)",
                )
            ]
        )
    from service import kinds  # the registry, built-in kinds and plugins loaded

    if key.startswith("params."):
        name = key.split(".")[1]
        known = sorted({f for k in kinds.all_kinds().values() for f in k.params.model_fields})
        if name not in known:
            close = difflib.get_close_matches(name, known, n=3)
            hint = f"; did you mean {' or '.join(repr('params.' + c) for c in close)}?"
            raise SpecError(
                [(where, f"{key!r}: no kind has a param {name!r}{hint if close else ''}")]
            )
    if key.startswith("metric."):
        kinds.load()
        why = unknown_metric(
            key.split(".", 1)[1], declared_metrics(), column=True, prefix="metric."
        )
        if why is not None:
            raise SpecError([(where, f"{key!r}: {why}")])
    return key


def metric_of(key: str) -> str:
    """The row metric a ``metric.<name>`` key reads (an old name resolved: ``metric.smape``
    reads ``brdf.smape``)."""
    name = key.split(".", 1)[1]
    return one_column(name) or name


def parse_keys(texts: Iterable[str], where: str = "query.columns") -> list[str]:
    """Column keys from repeated and/or comma-separated ``texts``, in order, once each."""
    keys: list[str] = []
    for text in texts:
        for part in text.split(","):
            if part.strip() and part.strip() not in keys:
                keys.append(check_key(part.strip(), where))
    if len(keys) > MAX_KEYS:
        raise SpecError([(where, f"at most {MAX_KEYS} columns")])
    return keys


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


@dataclass(frozen=True)
class JobFilter:
    """One parsed filter: ``key op value`` (``value`` as typed)."""

    key: str
    op: str
    value: str

    def passes(self, actual: Any) -> bool:
        """Whether a job whose value for :attr:`key` is ``actual`` passes (``None``: the job
        has no such value, and never passes)."""
        if actual is None:
            return False
        if isinstance(actual, bool):
            got_num: float | None = None
            got_text = "true" if actual else "false"
        elif isinstance(actual, int | float):
            got_num, got_text = float(actual), repr(actual)
        elif isinstance(actual, str):
            got_num, got_text = _number(actual), actual
        else:
            got_num, got_text = None, json.dumps(actual, sort_keys=True)
        want = _number(self.value)
        if self.op in _ORDER:
            return got_num is not None and want is not None and _ORDER[self.op](got_num, want)
        if got_num is not None and want is not None:
            same = math.isclose(got_num, want, rel_tol=1e-12, abs_tol=0.0)  # "0.1" vs 0.1
        else:
            same = got_text == self.value
        return same if self.op == "=" else not same


def parse_filters(texts: Iterable[str], where: str = "query.filter") -> list[JobFilter]:
    """Filters from ``texts`` (each ``key op value``); :class:`SpecError` naming ``where``
    and the text for one that does not parse."""
    out = []
    for text in texts:
        m = _FILTER.fullmatch(text)
        if m is None:
            raise _not_a_filter(text, where)
        if m[2] is not None:
            out.append(JobFilter(check_key(m[1], where), m[2], m[3].rstrip(" ")))
        else:
            out.append(JobFilter(check_key(m[1], where), m[4], m[5]))
    if len(out) > MAX_KEYS:
        raise SpecError([(where, f"at most {MAX_KEYS} filters")])
    return out


def _not_a_filter(text: str, where: str) -> SpecError:
    """What is wrong with ``text``, which does not match :data:`FILTER_PATTERN`."""
    m = _LOOSE.match(text)
    if m is not None and m[3]:
        check_key(m[1], where)  # raises naming the column
        if m[2] in _ORDER:
            return SpecError([(where, f"{text!r}: {m[2]} needs a number, got {m[3]!r}")])
    return SpecError(
        [
            (
                where,
                f"{text!r} is not a filter: use <column><op><value> with op one of "
                "=, !=, <, <=, >, >= (e.g. params.model=hybrid, metric.brdf.smape<0.1); "
                "an order (<, <=, >, >=) takes a decimal number",
            )
        ]
    )


def param_value(spec: Mapping[str, Any], key: str) -> Any:
    """The value of ``params.<path>`` in a job's ``spec`` (``None`` when it has none)."""
    value: Any = spec.get("params")
    for part in key.split(".")[1:]:
        if isinstance(value, Mapping) and part in value:
            value = value[part]
        elif isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        else:
            return None
    return value


def metric_means(rows: Iterable[Any]) -> dict[str, float]:
    """The mean value of each metric over ``rows`` (:class:`jobapi.rows.ResultRow`), finite
    values only; a metric with ``test`` rows is the mean of those (the held-out error)."""
    rows = list(rows)
    tested = {r.metric for r in rows if getattr(r, "split", None) == "test"}
    sums: dict[str, list[float]] = {}
    for r in rows:
        if r.metric in tested and getattr(r, "split", None) != "test":
            continue
        v = r.value
        if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
            sums.setdefault(r.metric, []).append(float(v))
    return {m: sum(vs) / len(vs) for m, vs in sums.items()}


def job_values(
    spec: Mapping[str, Any], keys: Iterable[str], metrics: Callable[[], Mapping[str, float]]
) -> dict[str, Any]:
    """The value of each key for one job; ``metrics`` is called (once) only when a
    ``metric.`` key is asked for."""
    out: dict[str, Any] = {}
    means: Mapping[str, float] | None = None
    for key in keys:
        if key.startswith("params."):
            out[key] = param_value(spec, key)
        else:
            if means is None:
                means = metrics()
            out[key] = means.get(metric_of(key))
    return out


def cell_text(doc: Mapping[str, Any], key: str) -> str:
    """A job document's value for ``key`` (from its ``columns``, as ``GET /api/jobs``
    gives them) as table text: numbers to 4 significant digits, nested values as JSON."""
    value = (doc.get("columns") or {}).get(key)
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict | list):
        return json.dumps(value, sort_keys=True)
    return str(value)
