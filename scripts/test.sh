#!/usr/bin/env bash
# Sets up (if needed) and runs the whole test suite. Extra arguments go to pytest.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# the run's compiled kernels live in this checkout (.kcache), never in a cache other installs share
export RSRIVC_CACHE_DIR="${RSRIVC_CACHE_DIR:-$ROOT/.kcache}"
bash "$ROOT/scripts/bootstrap.sh" >/dev/null
# shellcheck source=/dev/null
source "$ROOT/scripts/env.sh"
cd "$ROOT"
exec python -m pytest "$@"
