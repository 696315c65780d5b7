"""schemathesis against ``/openapi.json`` (issue 15, B7; issue 21, item 12): every operation of
the in-process app, bounded in examples and time, under every check schemathesis has
(``--checks all``): no 5xx, responses that match the documented schema, schema-valid requests
accepted and invalid ones refused."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.config import SchemathesisConfig

from service import kinds
from service.api import create_app
from service.settings import Settings

pytestmark = pytest.mark.slow

_DATA_DIR = Path(tempfile.mkdtemp(prefix="matforge-schemathesis-"))
kinds.load_builtin()
APP = create_app(Settings.from_env({}).with_(data_dir=_DATA_DIR))
#: ``POST /api/jobs`` takes a ``oneOf`` with one variant per registered kind: schemathesis's
#: coverage phase enumerates ~10,000 boundary cases from it (40-80 s here, alone over the
#: time budget), so for that one operation only the examples and fuzzing phases run (bounded
#: by ``max_examples``); tests/e2e/test_api_fuzz.py and test_api_hardening.py send it the
#: hostile bodies. Every other operation runs all three phases.
#:
#: Every check runs (``--checks all``; issue 21, item 12). ``positive_data_acceptance``
#: expects a schema-valid request to be accepted; these operations answer 422 to some
#: schema-valid requests by rules a JSON schema cannot state, each documented on the route
#: (``status_code_conformance`` checks that the 422 is in its responses):
#:
#: - ``POST /api/jobs``: a kind's cross-field rules (``select``'s), refs that must exist;
#: - ``POST /api/results/batch``: a step's spec, validated as ``POST /api/jobs`` does;
#: - ``POST /api/artifacts``: the bytes must be a valid file of the type the name says (a
#:   name with no known extension has no type);
#: - the ``{job_id}`` routes: a prefix shared by several jobs is ambiguous.
#: - ``GET /api/jobs`` and ``GET /api/results``: a column, metric or kind named in a filter
#:   or a query must be one the registered kinds declare (refused naming the closest ones).
_SEMANTIC_422 = {
    "positive_data_acceptance": {
        "expected-statuses": ["2xx", "3xx", "401", "403", "404", "409", "422", "429", "5xx"]
    }
}
CONFIG = SchemathesisConfig.from_dict(
    {
        "operations": [
            {
                "include-path": "/api/jobs",
                "include-method": "POST",
                "phases": {"coverage": {"enabled": False}},
                "checks": _SEMANTIC_422,
            },
            {"include-path": "/api/results/batch", "checks": _SEMANTIC_422},
            {"include-path": "/api/artifacts", "include-method": "POST", "checks": _SEMANTIC_422},
            {"include-path-regex": r"\{job_id\}", "checks": _SEMANTIC_422},
            {"include-path": "/api/jobs", "include-method": "GET", "checks": _SEMANTIC_422},
            {"include-path": "/api/results", "include-method": "GET", "checks": _SEMANTIC_422},
        ]
    }
)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP, config=CONFIG)


@pytest.fixture(scope="module", autouse=True)
def _cleanup() -> Iterator[None]:
    yield
    APP.state.upload_checker.close()
    shutil.rmtree(_DATA_DIR, ignore_errors=True)


@schema.parametrize()
@settings(
    max_examples=20,
    deadline=2000,
    suppress_health_check=list(HealthCheck),
    derandomize=True,
)
def test_api_conforms(case: schemathesis.Case) -> None:
    case.call_and_validate()  # no ``checks=``: all of them, configured by CONFIG
