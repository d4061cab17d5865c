#!/usr/bin/env bash
# Main job: set up (if needed), then diagnose the bundled simulated beam recording offline with the
# same estimator and fault logic the live node runs. Prints a per-mode summary; writes the report to
# out/beam_fault/report.html (plus estimates.csv, events.csv, summary.json).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/bootstrap.sh" >/dev/null
# shellcheck source=/dev/null
source "$ROOT/scripts/env.sh"
cd "$ROOT"
rsrivc_diagnose bags/beam_fault --params-file config/beam_fault.yaml --out out/beam_fault "$@"
echo "report: $ROOT/out/beam_fault/report.html"
