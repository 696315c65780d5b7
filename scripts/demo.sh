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
# The fabric step's Fig. 2-style preview, the glint and BTF steps: their job pages.
MF="$MF" bash scripts/demo_links.sh "$DATA/demo-results.csv" "$URL"
echo "Dashboard: $URL/   (the service keeps running; stop it with: kill \$(cat $DATA/serve.pid))"
