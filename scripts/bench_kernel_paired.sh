#!/usr/bin/env bash
# Paired timing of the per-sample kernel (rsrivc_bench's case k4_4096hz_closed_1_0: K = 4 beam at 4096 Hz, closed
# loop, (M_l, M_s) = (1, 0)): this tree against another revision, alternated, each in a fresh process with its own
# ahead-of-time kernels (rsrivc_warmup --if-needed in each tree). Per process the fastest of 15 runs counts.
#   bash scripts/bench_kernel_paired.sh REV [ROUNDS]
# prints each tree's per-process figures in us/sample (sorted), then the best and the median of them.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
REV="$1"; ROUNDS="${2:-10}"
source "$ROOT/scripts/env.sh"
WT="$(mktemp -d -t rsrivc-kpaired-XXXX)"
trap 'git -C "$ROOT" worktree remove --force "$WT" >/dev/null 2>&1 || true' EXIT
git -C "$ROOT" worktree add -f -q "$WT" "$REV"
for tree in "$WT" "$ROOT"; do (cd "$tree" && python -m additive_rsrivc_ros.warmup --if-needed >/dev/null 2>&1 \
  && python -m compileall -q additive_rsrivc_ros); done
# run from the tree's directory (stdin script: sys.path[0] is the working directory, so that tree's package)
CODE='
import numpy as np
from additive_rsrivc_ros.cli import bench
bench.REPEATS = 15
print(round(bench.bench_case("k4", 1, 0)["us_per_sample"], 4))
'
for i in $(seq "$ROUNDS"); do
  if (( i % 2 )); then order="$REV this"; else order="this $REV"; fi
  for name in $order; do
    tree="$ROOT"; [ "$name" = "$REV" ] && tree="$WT"
    echo "$name $(cd "$tree" && python - <<<"$CODE" | tail -1)"
  done
done | python -c '
import sys, collections, statistics
runs = collections.defaultdict(list)
for line in sys.stdin:
    name, v = line.split()
    runs[name].append(float(v))
for name, v in runs.items():
    v.sort()
    print(f"{name:>10}: best {v[0]:.3f}  median {statistics.median(v):.3f} us/sample  (" + " ".join(f"{x:.3f}" for x in v) + ")")
'
