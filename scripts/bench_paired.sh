#!/usr/bin/env bash
# Paired timing of rsrivc_diagnose: this tree against another revision, alternated (the order swapped every
# round: on a noisy machine the first process of a pair is often the slower one).
#   bash scripts/bench_paired.sh REV BAG PARAMS [ROUNDS]
# prints per run: tree, whole-process wall time, and the tool's own stages (summary.json timings_s).
# REV is checked out in a temporary worktree; each tree's kernels are warmed first (rsrivc_warmup --if-needed).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
REV="$1"; BAG="$(realpath "$2")"; PARAMS="$(realpath "$3")"; ROUNDS="${4:-5}"
source "$ROOT/scripts/env.sh"
WT="$(mktemp -d -t rsrivc-paired-XXXX)"; OUT="$(mktemp -d -t rsrivc-paired-out-XXXX)"
trap 'git -C "$ROOT" worktree remove --force "$WT" >/dev/null 2>&1 || true; rm -rf "$OUT"' EXIT
git -C "$ROOT" worktree add -f -q "$WT" "$REV"
for tree in "$WT" "$ROOT"; do (cd "$tree" && python -m additive_rsrivc_ros.warmup --if-needed >/dev/null 2>&1 \
  && python -m compileall -q additive_rsrivc_ros); done
run() {  # run NAME TREE: python -m from the tree's directory imports that tree's package
  local t0 t1
  t0=$(date +%s.%N)
  (cd "$2" && python -m additive_rsrivc_ros.cli.diagnose "$BAG" --params-file "$PARAMS" --out "$OUT/$1" --quiet \
    --no-progress >/dev/null)
  t1=$(date +%s.%N)
  python - "$1" "$t0" "$t1" "$OUT/$1/summary.json" <<'PY'
import json, sys
name, t0, t1, path = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
t = json.load(open(path))["timings_s"]
print(f"{name:5s} process {t1 - t0:.2f} s  " + "  ".join(f"{k} {v:.3f}" for k, v in t.items()))
PY
}
for i in $(seq "$ROUNDS"); do
  if (( i % 2 )); then run "$REV" "$WT"; run this "$ROOT"; else run this "$ROOT"; run "$REV" "$WT"; fi
done
