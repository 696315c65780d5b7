#!/usr/bin/env bash
# make demo: start the service (API, dashboard, workers) in the background, run the demo
# batch through the CLI, print the results table and the dashboard URL, leave it running.
set -euo pipefail
cd "$(dirname "$0")/.."
HOST=${HOST:-127.0.0.1}
PORT=${PORT:-8000}
DATA=${DATA:-./matforge-data}
WORKERS=${WORKERS:-1}
URL="http://$HOST:$PORT"
export MATFORGE_SERVER="$URL"
MF=.venv/bin/matforge
mkdir -p "$DATA"

if curl -fsS "$URL/api/health" >/dev/null 2>&1; then
  echo "matforge is already serving at $URL; using it." >&2
else
  echo "starting matforge at $URL (data in $DATA, log in $DATA/serve.log)" >&2
  nohup "$MF" serve --host "$HOST" --port "$PORT" --data-dir "$DATA" --workers "$WORKERS" \
    >"$DATA/serve.log" 2>&1 &
  echo $! >"$DATA/serve.pid"
  for _ in $(seq 1 120); do
    curl -fsS "$URL/api/health" >/dev/null 2>&1 && break
    if ! kill -0 "$(cat "$DATA/serve.pid")" 2>/dev/null; then
      echo "matforge serve exited; see $DATA/serve.log" >&2
      tail -n 20 "$DATA/serve.log" >&2
      exit 1
    fi
    sleep 0.5
  done
  curl -fsS "$URL/api/health" >/dev/null || { echo "server did not come up" >&2; exit 1; }
fi

"$MF" batch scripts/demo_batch.yaml --out "$DATA/demo-results.csv"
echo
echo "Results: $DATA/demo-results.csv"
# The fabric step's Fig. 2-style preview: its job page and the picture itself.
FABRIC_JOB=$(.venv/bin/python -c 'import csv, sys
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r["step"] == "fabric"]
print(rows[0]["job_id"] if rows and rows[0]["state"] == "succeeded" else "")' \
  "$DATA/demo-results.csv" 2>/dev/null || true)
if [ -n "$FABRIC_JOB" ]; then
  FABRIC_PNG=$("$MF" artifacts "$FABRIC_JOB" --json 2>/dev/null | .venv/bin/python -c 'import json, sys
print(next((a["digest"] for a in json.load(sys.stdin) if a["name"] == "preview.png"), ""))' \
    2>/dev/null || true)
  echo "Fabric dataset: $URL/jobs/$FABRIC_JOB"
  if [ -n "$FABRIC_PNG" ]; then
    echo "Fabric preview: $URL/api/artifacts/$FABRIC_PNG   (preview.png)"
  fi
fi
GLINT_JOB=$(.venv/bin/python -c 'import csv, sys
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r["step"] == "glint"]
print(rows[0]["job_id"] if rows and rows[0]["state"] == "succeeded" else "")' \
  "$DATA/demo-results.csv" 2>/dev/null || true)
if [ -n "$GLINT_JOB" ]; then
  echo "Glint example and NDF maps: $URL/jobs/$GLINT_JOB   (example.exr, ndf.npz, preview.png)"
fi
BTF_JOB=$(.venv/bin/python -c 'import csv, sys
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r["step"] == "btf"]
print(rows[0]["job_id"] if rows and rows[0]["state"] == "succeeded" else "")' \
  "$DATA/demo-results.csv" 2>/dev/null || true)
if [ -n "$BTF_JOB" ]; then
  echo "BTF slices: $URL/jobs/$BTF_JOB   (slices-XXXX.npz, btf.json, preview.png)"
fi
echo "Dashboard: $URL/   (the service keeps running; stop it with: kill \$(cat $DATA/serve.pid))"
