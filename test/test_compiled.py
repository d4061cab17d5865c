"""Kernels compiled ahead of time (issue 16, ``core/estimation/compiled.py``): a call is served by the extension only
with
exactly the exported argument types; anything else, and an extension built from other sources, goes to the JIT."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from additive_rsrivc_ros.core.estimation import compiled
from additive_rsrivc_ros.core.estimation.compiled import ArgSpec

REPO = Path(__file__).resolve().parents[1]
C2 = ArgSpec("array", "float64", 2, "C")
SPECS = (ArgSpec("float"), ArgSpec("int"), ArgSpec("bool"), C2, ArgSpec("array", "uint8", 1, "C", True))


def _args(**change):
    base = dict(x=0.5, n=3, flag=True, m=np.zeros((3, 2)), b=np.frombuffer(b"abc", dtype=np.uint8))
    base.update(change)
    return tuple(base.values())


def test_only_exactly_the_exported_types_match():
    assert compiled.matcher(SPECS)(*_args())
    assert compiled.matcher(SPECS)(*_args(x=np.float64(0.5), n=np.int32(3), flag=np.bool_(False)))
    assert compiled.matcher(SPECS)(*_args(b=np.zeros(3, np.uint8)))        # writable where read-only is exported
    wrong = {
        "an int for a float": _args(x=1),
        "a float32 scalar": _args(x=np.float32(0.5)),
        "a float for an int": _args(n=3.0),
        "a bool for an int": _args(n=True),
        "an int for a bool": _args(flag=1),
        "a transposed (F-ordered) array": _args(m=np.zeros((2, 3)).T),
        "a strided view": _args(m=np.zeros((3, 4))[:, ::2]),
        "float32 data": _args(m=np.zeros((3, 2), np.float32)),
        "int64 data": _args(m=np.zeros((3, 2), np.int64)),
        "one dimension too few": _args(m=np.zeros(6)),
        "a read-only array": _args(m=np.frombuffer(np.zeros(6).tobytes()).reshape(3, 2)),
        "a list": _args(m=[[0.0, 0.0]] * 3),
        "an ndarray subclass": _args(m=np.ma.zeros((3, 2))),
        "a byte-swapped array": _args(m=np.zeros((3, 2), ">f8")),
        "an argument too few": _args()[:-1],
    }
    for what, args in wrong.items():
        assert not compiled.matcher(SPECS)(*args), what
    unaligned = np.zeros(6 * 8 + 1, np.uint8)[1:].view(np.float64).reshape(3, 2)
    assert not unaligned.flags.aligned and not compiled.matcher(SPECS)(*_args(m=unaligned))
    assert compiled.matcher((ArgSpec("array", "float64", 2, "F"),))(np.zeros((2, 3)).T)
    assert compiled.matcher((ArgSpec("array", "float64", 2, "A"),))(np.zeros((3, 4))[:, ::2])
    assert compiled.matcher(())() and not compiled.matcher(())(1.0)


def _fake_extension(directory: Path, sources: dict, cpu: str = "generic") -> None:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "x.so").write_bytes(b"not a library")
    (directory / compiled.MANIFEST).write_text(json.dumps({
        "file": "x.so", "cpu": cpu, "ext_suffix": compiled.sysconfig.get_config_var("EXT_SUFFIX"), "sources": sources,
        "exports": {}}), encoding="utf-8")


def test_an_extension_of_other_sources_or_a_broken_one_is_not_loaded(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "stale"))
    stale = dict(compiled._source_digests())
    stale["core/estimation/zoh.py"] = "0" * 64                                      # one kernel module changed since
    _fake_extension(tmp_path / "stale", stale)
    assert compiled._load_extension() is None
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "broken"))
    _fake_extension(tmp_path / "broken", compiled._source_digests())    # right sources, not a library
    assert compiled._load_extension() is None
    real = tmp_path / "real"
    compiled.build(real, {})                                             # a real (empty) extension for this CPU
    manifest = json.loads((real / compiled.MANIFEST).read_text())
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(real))
    assert compiled._load_extension() is not None
    manifest["cpu"] = "another machine's"                                # e.g. a home directory shared by a cluster
    (real / compiled.MANIFEST).write_text(json.dumps(manifest))
    assert compiled._load_extension() is None
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty"))
    assert compiled._load_extension() is None


FALLBACK = r"""
import sys
import numpy as np
from additive_rsrivc_ros.core.estimation import compiled, zoh
assert compiled.extension_loaded()
def zoh_of(phi, gam):
    zoh.second_order_zoh(30.0, 4e4, 1.0 / 4096, phi, gam)
    return np.array(phi), np.array(gam)
ref = zoh_of(np.zeros((2, 2)), np.zeros(2))
assert "numba" not in sys.modules                                       # served ahead of time
big = np.zeros((2, 4))
strided = zoh_of(big[:, ::2], np.zeros(2))                              # a layout the extension was not built for
assert "numba" in sys.modules                                           # ... went to the JIT
assert np.array_equal(strided[0], ref[0]) and np.array_equal(big[:, ::2], ref[0]) and np.all(big[:, 1::2] == 0)
f32 = zoh_of(np.zeros((2, 2), np.float32), np.zeros(2, np.float32))     # a dtype it was not built for: no crash
assert np.allclose(f32[0], ref[0], rtol=1e-6) and np.allclose(f32[1], ref[1], rtol=1e-6)
again = zoh_of(np.zeros((2, 2)), np.zeros(2))                           # the process now runs the JIT throughout
assert np.array_equal(again[0], ref[0]) and np.array_equal(again[1], ref[1])
print("OK")
"""


def test_a_call_the_extension_was_not_built_for_goes_to_the_jit_with_the_same_result():
    if not _built():
        subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.warmup", "--if-needed", "--quiet"], env=_env(),
                       capture_output=True, text=True, cwd=REPO, timeout=900, check=True)
    assert _built(), "rsrivc_warmup built no ahead-of-time extension (see its output)"
    run = subprocess.run([sys.executable, "-c", FALLBACK], env=_env(), capture_output=True, text=True, cwd=REPO,
                         timeout=300)
    assert run.stdout.strip() == "OK", run.stdout + run.stderr


def _env() -> dict:
    return {k: v for k, v in os.environ.items() if k not in (compiled.MODE_ENV, "NUMBA_DISABLE_JIT")}


def _built() -> bool:
    code = "from additive_rsrivc_ros.core.estimation import compiled, zoh; print(compiled.extension_loaded())"
    run = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, cwd=REPO)
    return run.stdout.strip() == "True"


def _axpy(a, x, y):
    for i in range(x.size):
        y[i] += a * x[i]


def test_build_writes_an_extension_and_a_manifest_that_load(tmp_path, monkeypatch):
    """A small build (one kernel met with two signatures, one of them not exportable) into an empty directory loads,
    serves exactly its export with the JIT's result; a rebuild writes a new file and removes those older than 10 min."""
    from numba import njit

    disp = njit(cache=False)(_axpy)
    x, y = np.arange(5.0), np.ones(5)
    disp(2.0, x, y)
    disp(np.float32(2.0), x.astype(np.float32), np.ones(5, np.float32))   # float32: left to the JIT
    count, _ = compiled.build(tmp_path, {"test.axpy": disp})
    assert count == 1
    first = json.loads((tmp_path / compiled.MANIFEST).read_text())["file"]
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    module, exports = compiled._load_extension()
    (export, specs), = exports["test.axpy"]
    assert specs == (ArgSpec("float"), ArgSpec("array", "float64", 1, "C"), ArgSpec("array", "float64", 1, "C"))
    y2 = np.ones(5)
    getattr(module, export)(2.0, x, y2)
    assert np.array_equal(y2, y) and np.array_equal(y, 1.0 + 2.0 * x)
    compiled.build(tmp_path, {"test.axpy": disp})
    files = sorted(p.name for p in tmp_path.glob(compiled.EXTENSION + "-*"))
    assert len(files) == 2 and first in files           # the first is younger than 10 min: kept
    now = json.loads((tmp_path / compiled.MANIFEST).read_text())["file"]
    assert now != first and now in files
    os.utime(tmp_path / first, (0, 0))                  # an old extension: removed by the next build
    compiled.build(tmp_path, {"test.axpy": disp})
    files = sorted(p.name for p in tmp_path.glob(compiled.EXTENSION + "-*"))
    assert first not in files and now in files and len(files) == 2
