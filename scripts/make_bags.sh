#!/usr/bin/env bash
# Regenerate the bundled recordings in bags/. Deterministic: the same code gives the same bytes
# (checked against bags/SHA256SUMS with --check). Total size ~13 MB (MCAP message indexes are ~60 % of it).
#   bash scripts/make_bags.sh            # rewrite bags/beam and bags/beam_fault
#   bash scripts/make_bags.sh --check    # regenerate into a temp dir and compare with bags/SHA256SUMS
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/env.sh"
OUT="$ROOT/bags"
CHECK=0
if [[ "${1:-}" == "--check" ]]; then CHECK=1; OUT="$(mktemp -d)"; trap 'rm -rf "$OUT"' EXIT; fi

make_bag() {  # name, then rsrivc_simulate arguments
  local name="$1"; shift
  rm -rf "${OUT:?}/$name"
  rsrivc_simulate --out "$OUT/$name" "$@"
}
# beam: 20 s at 4096 Hz, mode 2's frequency down 10 % and back over [5, 19] s (a compressed version of the
# paper's [40, 100] s manipulation; mode-2 memory is 0.244 s), estimator params config/beam.yaml
make_bag beam --scenario beam --duration 20 --seed 0 \
  --set manipulation_start_s=5 --set manipulation_end_s=19
# beam_fault: 20 s, healthy until 10 s, then a 5 % step drop of mode 2's frequency; params config/beam_fault.yaml
make_bag beam_fault --scenario beam_fault --duration 30 --seed 0 --set fault_time_s=20

(cd "$OUT" && find beam beam_fault -type f | LC_ALL=C sort | xargs sha256sum) > "$OUT/SHA256SUMS.new"
if [[ $CHECK == 1 ]]; then
  diff "$ROOT/bags/SHA256SUMS" "$OUT/SHA256SUMS.new" && echo "bags/ is reproducible: identical bytes"
else
  mv "$OUT/SHA256SUMS.new" "$OUT/SHA256SUMS"
  du -sh "$OUT"/beam "$OUT"/beam_fault
fi
