#!/usr/bin/env bash
# Idempotent environment bootstrap: a local venv (.venv) from PyPI with pinned versions, ROS 2 Jazzy
# from the ros-jazzy-* wheels, and this package installed (editable) so the console scripts are on PATH.
# A second run only checks a stamp and re-links the package: it takes seconds.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${RSRIVC_VENV:-$ROOT/.venv}"
PY="${PYTHON:-python3}"
REQ="$ROOT/requirements/requirements.txt"
CON="$ROOT/requirements/constraints.txt"
STAMP="$VENV/.rsrivc-requirements.sha256"

if [ ! -x "$VENV/bin/python" ]; then
  echo "[bootstrap] creating venv at $VENV" >&2
  "$PY" -m venv "$VENV"
fi
want="$(cat "$REQ" "$CON" "$ROOT/setup.py" | sha256sum | cut -d' ' -f1)"
have="$(cat "$STAMP" 2>/dev/null || true)"
if [ "$want" != "$have" ]; then
  echo "[bootstrap] installing pinned requirements (first run takes about a minute)" >&2
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade "pip<26"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$REQ" -c "$CON"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e "$ROOT"
  echo "$want" > "$STAMP"
fi
# byte-compile the package (a no-op when up to date): with PYTHONDONTWRITEBYTECODE set, as on this machine image,
# Python never writes these caches itself and every process compiled the package's modules again (about 0.5 s)
"$VENV/bin/python" -m compileall -q "$ROOT/additive_rsrivc_ros" >/dev/null || true
# compile the numba kernels into the user cache now, not on the first run (a no-op when they are cached)
"$VENV/bin/python" -m additive_rsrivc_ros.warmup --if-needed
echo "$VENV"
