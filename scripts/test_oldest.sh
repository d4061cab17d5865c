#!/usr/bin/env bash
# The oldest supported stack (requirements/oldest.txt: the floors setup.py and package.xml declare), without ROS:
# a second venv (.venv-oldest) with exactly those versions and this package installed from source (not editable),
# then a smoke subset: rsrivc_diagnose on the bundled fault bag (the verdict must be FAULT), rsrivc_monitor's and
# rsrivc_replay's one-line answer without ROS, and the core numerics tests. The kernels compile under that numba
# into their own cache (the cache is keyed per install). Extra arguments go to pytest.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${RSRIVC_OLDEST_VENV:-$ROOT/.venv-oldest}"
PY="${PYTHON:-python3}"
REQ="$ROOT/requirements/oldest.txt"
STAMP="$VENV/.rsrivc-oldest.sha256"
export RSRIVC_CACHE_DIR="${RSRIVC_CACHE_DIR:-$ROOT/.kcache}"
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1

[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
want="$(cat "$REQ" | sha256sum | cut -d' ' -f1)"
if [ "$want" != "$(cat "$STAMP" 2>/dev/null || true)" ]; then
  echo "[oldest] installing requirements/oldest.txt into $VENV" >&2
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$REQ"
  echo "$want" > "$STAMP"
fi
# the package itself, from this source tree (a wheel build: what `pip install .` gives a user), again only when the
# sources changed: a reinstall gives every file a new time, and numba then recompiles every kernel (about 3 min)
src="$(cd "$ROOT" && find additive_rsrivc_ros config bags setup.py setup.cfg package.xml -type f \
       ! -path '*__pycache__*' -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)"
if [ "$src" != "$(cat "$VENV/.rsrivc-source.sha256" 2>/dev/null || true)" ]; then
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation \
    --force-reinstall "$ROOT"
  echo "$src" > "$VENV/.rsrivc-source.sha256"
fi
"$VENV/bin/python" - <<'PY'
import importlib.metadata as md
print("[oldest] " + ", ".join(f"{n} {md.version(n)}" for n in ("numpy", "scipy", "numba", "rosbags", "PyYAML")))
PY

out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
t0=$SECONDS
"$VENV/bin/rsrivc_diagnose" "$ROOT/bags/beam_fault" --params-file "$ROOT/config/beam_fault.yaml" --out "$out/diag" \
  --quiet --no-report --no-progress
"$VENV/bin/python" - "$out/diag/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
assert s["verdict"] == "FAULT" and "Error" not in s["verdict_text"], s["verdict_text"]
print(f"[oldest] rsrivc_diagnose bags/beam_fault: {s['verdict']}, monitored {s['monitored_s']} s")
PY
echo "[oldest] diagnosis took $((SECONDS - t0)) s (with numba compiling the kernels unless cached)" >&2
if "$VENV/bin/rsrivc_monitor" --ros-args 2>"$out/monitor.err"; then
  echo "[oldest] rsrivc_monitor ran without ROS" >&2; exit 1
fi
[ "$(wc -l < "$out/monitor.err")" -eq 1 ] && grep -q "is not installed" "$out/monitor.err" \
  || { echo "[oldest] rsrivc_monitor without ROS did not answer in one line:" >&2; cat "$out/monitor.err" >&2; exit 1; }
if "$VENV/bin/rsrivc_replay" "$ROOT/bags/beam_fault" 2>"$out/replay.err"; then
  echo "[oldest] rsrivc_replay ran without ROS" >&2; exit 1
fi
[ "$(wc -l < "$out/replay.err")" -eq 1 ] && grep -q "ROS 2 Jazzy is not installed" "$out/replay.err" \
  || { echo "[oldest] rsrivc_replay without ROS did not answer in one line:" >&2; cat "$out/replay.err" >&2; exit 1; }
echo "[oldest] rsrivc_monitor and rsrivc_replay without ROS: one line each, saying what to install" >&2
cd "$out"   # the installed package, not the source tree, is imported by the tests
"$VENV/bin/python" -m pytest -p no:cacheprovider --rootdir "$ROOT/test" -c "$ROOT/pytest.ini" \
  "$ROOT/test/test_zoh.py" "$ROOT/test/test_kernel.py" "$ROOT/test/test_filters.py" \
  "$ROOT/test/test_report_numbers.py" "$ROOT/test/test_modefind.py" "$@"
