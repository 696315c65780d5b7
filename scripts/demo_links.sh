#!/usr/bin/env bash
# The links `make demo` prints after its batch: the job pages of the fabric, glint and BTF
# steps (and the fabric preview's URL), found in the batch's result rows.
# Usage: scripts/demo_links.sh RESULTS.csv URL   (MF, PY: the matforge and python to use)
set -uo pipefail
RESULTS=$1
URL=$2
MF=${MF:-.venv/bin/matforge}
PY=${PY:-.venv/bin/python}

# The job of a step: the `job` column of its first result row (a step has rows only when
# it succeeded), or nothing.
step_job() {
  "$PY" -c 'import csv, sys
rows = [r for r in csv.DictReader(open(sys.argv[1], newline="")) if r.get("step") == sys.argv[2]]
print(rows[0].get("job") or "" if rows else "")' "$RESULTS" "$1" 2>/dev/null || true
}

FABRIC_JOB=$(step_job fabric)
if [ -n "$FABRIC_JOB" ]; then
  FABRIC_PNG=$("$MF" artifacts "$FABRIC_JOB" --json 2>/dev/null | "$PY" -c 'import json, sys
print(next((a["digest"] for a in json.load(sys.stdin) if a["name"] == "preview.png"), ""))' \
    2>/dev/null || true)
  echo "Fabric dataset: $URL/jobs/$FABRIC_JOB"
  if [ -n "$FABRIC_PNG" ]; then
    echo "Fabric preview: $URL/api/artifacts/$FABRIC_PNG   (preview.png)"
  fi
fi
GLINT_JOB=$(step_job glint)
if [ -n "$GLINT_JOB" ]; then
  echo "Glint example and NDF maps: $URL/jobs/$GLINT_JOB   (example.exr, ndf.npz, preview.png)"
fi
BTF_JOB=$(step_job btf)
if [ -n "$BTF_JOB" ]; then
  echo "BTF slices: $URL/jobs/$BTF_JOB   (slices-XXXX.npz, btf.json, preview.png)"
fi
