"""Incremental ``rsrivc_fleet`` runs: a recording already diagnosed with the same inputs is not diagnosed again.

A bag's result (what :func:`.fleet.run_bag` returns) is stored in ``DIR/.fleet_cache/<key>.json`` under the key
``sha256(bag content, params file content, node name, report on/off, output folder, package fingerprint)``:

* bag content: SHA-256 of every file of the bag folder (relative path and bytes, in sorted order). The digest of
  a file is remembered by (path, size, modification time) in ``DIR/.fleet_cache/files.json``, so a later run reads
  only new or changed files;
* package fingerprint: the package version and a hash of its Python sources (a changed estimator, fault logic or
  level computation recomputes everything).

A stored result is reused only if the bag's output folder ``DIR/<bag name>/summary.json`` is still the one that
run wrote (its SHA-256 is stored with the result); otherwise the bag is diagnosed again. The machine grouping and
the drift tests are not cached: they are recomputed from all results on every run (milliseconds).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

CACHE_DIRNAME = ".fleet_cache"
SCHEMA = 1                      # layout of a stored result; bump when run_bag's result changes meaning
_CHUNK = 1 << 20
_PACKAGE = Path(__file__).resolve().parents[1]
_TASK_FIELDS = ("name", "bag", "params_file", "machine")   # of the task, not of the content: set on reuse


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        while block := fh.read(_CHUNK):
            h.update(block)
    return h.hexdigest()


def package_fingerprint() -> str:
    """The package version and SHA-256 (16 hex digits) of its Python sources, in a fixed order."""
    from .. import __version__

    h = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        h.update(str(path.relative_to(_PACKAGE)).encode())
        h.update(path.read_bytes())
    return f"{__version__}-{h.hexdigest()[:16]}"


class ResultCache:
    """The cache of one output folder (module docstring). ``enabled=False``: never reuse, still store."""

    def __init__(self, out: Path, enabled: bool = True) -> None:
        self.dir = Path(out) / CACHE_DIRNAME
        self.enabled = enabled
        self.package = package_fingerprint()
        self._memo: dict[str, list[Any]] = self._load_memo()
        self.reused = 0
        self.hashed_bytes = 0

    def _load_memo(self) -> dict[str, list[Any]]:
        try:
            data = json.loads((self.dir / "files.json").read_text(encoding="utf-8"))
            return data if isinstance(data, dict) else {}
        except (OSError, ValueError):
            return {}

    def file_digest(self, path: Path) -> str:
        """SHA-256 of one file, remembered by (absolute path, size, modification time in ns)."""
        st = path.stat()
        key = str(path.resolve())
        hit = self._memo.get(key)
        if isinstance(hit, list) and len(hit) == 3 and hit[0] == st.st_size and hit[1] == st.st_mtime_ns:
            return str(hit[2])
        digest = _file_sha256(path)
        self.hashed_bytes += st.st_size
        self._memo[key] = [st.st_size, st.st_mtime_ns, digest]
        return digest

    def bag_digest(self, bag: Path) -> str:
        """SHA-256 over the bag folder's files (relative paths and contents)."""
        h = hashlib.sha256()
        files = sorted(p for p in Path(bag).rglob("*") if p.is_file())
        for p in files:
            h.update(str(p.relative_to(bag)).encode())
            h.update(self.file_digest(p).encode())
        return h.hexdigest()

    def key(self, bag: str, params_file: str, node_name: str | None, report: bool, out_dir: str = "",
            time_range: tuple[str | None, str | None] = (None, None)) -> str:
        """The cache key of one task (module docstring; two copies of one bag have their own output folders;
        ``time_range``: ``--start``/``--end`` as given)."""
        parts = {"schema": SCHEMA, "bag": self.bag_digest(Path(bag)), "params": _file_sha256(Path(params_file)),
                 "node_name": node_name or "", "report": bool(report), "out_dir": str(out_dir),
                 "package": self.package}
        if time_range != (None, None):      # (absent otherwise: the keys of earlier runs stay valid)
            parts["time_range"] = list(time_range)
        return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()

    def lookup(self, key: str, out_dir: str, task_fields: Mapping[str, Any]) -> dict[str, Any] | None:
        """The stored result of ``key`` if its output folder is intact, with the task's own fields; else None."""
        if not self.enabled:
            return None
        try:
            entry = json.loads((self.dir / f"{key}.json").read_text(encoding="utf-8"))
            summary = Path(out_dir) / "summary.json"
            if not summary.is_file() or _file_sha256(summary) != entry["summary_sha256"]:
                return None
            result = dict(entry["result"])
        except (OSError, ValueError, KeyError, TypeError):
            return None
        result.update({k: task_fields[k] for k in _TASK_FIELDS if k in task_fields}, cached=True)
        self.reused += 1
        return result

    def store(self, key: str, out_dir: str, result: Mapping[str, Any]) -> None:
        """Remember a diagnosed bag's result (failed bags are not stored: they are tried again next run)."""
        if not result.get("ok"):
            return
        from .atomic import atomic_write_text

        try:
            entry = {"schema": SCHEMA, "summary_sha256": _file_sha256(Path(out_dir) / "summary.json"),
                     "result": {k: v for k, v in result.items() if k != "cached"}}
            self.dir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.dir / f"{key}.json", json.dumps(entry, allow_nan=True) + "\n")
        except OSError:
            pass                  # a cache that cannot be written costs a recomputation next time, nothing else

    def save(self) -> None:
        """Write the file-digest memo (atomically)."""
        from .atomic import atomic_write_text

        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            live = {k: v for k, v in self._memo.items() if os.path.exists(k)}
            atomic_write_text(self.dir / "files.json", json.dumps(live) + "\n")
        except OSError:
            pass
