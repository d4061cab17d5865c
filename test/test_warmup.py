"""Cold start (issue 16): the kernel cache is keyed on the kernels' source, user-writable, and complete after
``rsrivc_warmup`` (a fresh process diagnosing a bag compiles nothing)."""
import os
import subprocess
import sys
from pathlib import Path

from additive_rsrivc_ros import numba_cache
from additive_rsrivc_ros.core.estimation import compiled

REPO = Path(__file__).resolve().parents[1]


def _child_cache_dir(env: dict) -> str:
    code = "import additive_rsrivc_ros as p; print(p.NUMBA_CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True, cwd=REPO)
    return out.stdout.strip()


def test_cache_dir_changes_with_any_kernel_source(tmp_path, monkeypatch):
    pkg = tmp_path / "pkg"
    (pkg / "core").mkdir(parents=True)
    (pkg / "core" / "zoh.py").write_text("x = 1\n")
    (pkg / "core" / "kernel.py").write_text("y = 2\n")
    (pkg / "node.py").write_text("z = 3\n")
    monkeypatch.setattr(numba_cache, "_PACKAGE", pkg)
    base = numba_cache.source_hash()
    (pkg / "node.py").write_text("z = 4\n")            # not a kernel module: same cache
    assert numba_cache.source_hash() == base
    (pkg / "core" / "zoh.py").write_text("x = 2\n")    # a callee changed: a different cache, never a stale load
    assert numba_cache.source_hash() != base


def test_user_cache_dir_is_respected_and_inherited_auto_dir_is_recomputed(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", numba_cache.AUTO_MARKER)}
    env["RSRIVC_CACHE_DIR"] = str(tmp_path / "root")
    auto = _child_cache_dir(env)
    assert Path(auto).parent == tmp_path / "root" and Path(auto).is_dir()
    assert Path(auto).name.endswith(f"-{numba_cache.source_hash()}-{numba_cache.install_hash()}")
    # a parent's automatic choice (e.g. from another checkout) is recomputed, not trusted
    stale = str(tmp_path / "root" / "numba-0-stale")
    assert _child_cache_dir({**env, "NUMBA_CACHE_DIR": stale, numba_cache.AUTO_MARKER: stale}) == auto
    # the user's own choice is kept as is
    mine = str(tmp_path / "mine")
    assert _child_cache_dir({**env, "NUMBA_CACHE_DIR": mine}) == mine


def test_cache_dir_is_per_install(tmp_path, monkeypatch):
    """Two installs of the same sources (another checkout or copy, another venv, another numpy) never share compiled
    kernels: a copy of the package imported from elsewhere picks another directory under the same root."""
    import shutil

    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", numba_cache.AUTO_MARKER)}
    env["RSRIVC_CACHE_DIR"] = str(tmp_path / "root")
    here = Path(_child_cache_dir(env))
    copy = tmp_path / "elsewhere"
    shutil.copytree(REPO / "additive_rsrivc_ros", copy / "additive_rsrivc_ros",
                    ignore=shutil.ignore_patterns("__pycache__"))
    code = "import additive_rsrivc_ros as p; print(p.__file__); print(p.NUMBA_CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "PYTHONPATH": str(copy)}, capture_output=True,
                         text=True, check=True, cwd=tmp_path).stdout.split()
    assert Path(out[0]).is_relative_to(copy), out                 # the copy was imported, not this checkout
    there = Path(out[1])
    assert there.parent == here.parent and there != here, (here, there)
    assert there.name.split("-")[2] == here.name.split("-")[2]    # same sources, another install
    base = numba_cache.install_hash()
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "venv2"))  # another environment
    assert numba_cache.install_hash() != base
    monkeypatch.undo()
    monkeypatch.setattr(numba_cache, "_installed", lambda m: f"{m}-0.0")   # another numpy/numba/llvmlite
    assert numba_cache.install_hash() != base


def test_unwritable_cache_root_falls_back(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("RSRIVC_CACHE_DIR", str(blocker / "cache"))   # cannot be created under a file
    got = numba_cache.cache_dir()
    assert not str(got).startswith(str(blocker)) and got.is_dir()


MISSES = """
import sys
from additive_rsrivc_ros.cli import diagnose
from additive_rsrivc_ros.warmup import kernel_dispatchers
code = diagnose.main(sys.argv[1:])
missed = {n: dict(d.stats.cache_misses) for n, d in kernel_dispatchers().items() if d.stats.cache_misses}
hits = sum(sum(d.stats.cache_hits.values()) for d in kernel_dispatchers().values())
print("EXIT", code, "MISSED", missed, "HITS", hits)
"""


AHEAD = """
import sys
from additive_rsrivc_ros.cli import diagnose
from additive_rsrivc_ros.core.estimation import compiled
code = diagnose.main(sys.argv[1:])
print("EXIT", code, "EXTENSION", compiled.extension_loaded(), "NUMBA", "numba" in sys.modules)
"""


def _warm_env() -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", numba_cache.AUTO_MARKER, compiled.MODE_ENV, "NUMBA_DISABLE_JIT")}
    warm = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.warmup", "--if-needed", "--check", "--quiet"],
                          env=env, capture_output=True, text=True, cwd=REPO, timeout=900)
    assert warm.returncode == 0, warm.stderr                   # --check: every kernel was compiled by the warm-up
    return env


def _diagnose(script: str, env: dict, out: Path) -> str:
    run = subprocess.run([sys.executable, "-c", script, str(REPO / "bags" / "beam_fault"), "--params-file",
                          str(REPO / "config" / "beam_fault.yaml"), "--out", str(out), "--quiet",
                          "--no-report", "--no-progress"], env=env, capture_output=True, text=True, cwd=REPO,
                         timeout=600)
    return run.stdout + run.stderr


def test_after_warmup_a_fresh_diagnosis_compiles_nothing(tmp_path):
    env = _warm_env()
    got = _diagnose(MISSES, {**env, compiled.MODE_ENV: "jit"}, tmp_path / "out")     # the JIT's cache
    assert "EXIT 0 MISSED {} HITS" in got, got
    assert int(got.split("HITS")[1].split()[0]) > 0            # the kernels were loaded from the cache


def test_after_warmup_a_fresh_diagnosis_runs_ahead_of_time_without_numba_and_equals_the_jit(tmp_path):
    """The extension serves every kernel the diagnosis calls (numba is never imported) with the JIT's results."""
    env = _warm_env()
    got = _diagnose(AHEAD, env, tmp_path / "aot")
    assert "EXIT 0 EXTENSION True NUMBA False" in got, got
    assert "EXIT 0" in _diagnose(AHEAD, {**env, compiled.MODE_ENV: "jit"}, tmp_path / "jit")
    for name in ("estimates.csv", "events.csv"):
        assert (tmp_path / "aot" / name).read_text() == (tmp_path / "jit" / name).read_text(), name


def test_a_failed_ahead_of_time_build_leaves_the_jit_serving_with_one_line(tmp_path, monkeypatch, capsys):
    """No C compiler (or any toolchain failure): the warm-up says so in one line and goes on; nothing is loaded."""
    from additive_rsrivc_ros import warmup

    def no_compiler(directory, dispatchers):
        raise OSError("error: command 'gcc' failed: No such file or directory")

    monkeypatch.setattr(compiled, "build", no_compiler)
    monkeypatch.setattr(warmup, "kernel_dispatchers", dict)
    warmup._build_extension(tmp_path, verbose=True)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no ahead-of-time kernels (OSError" in err[0] and "JIT cache serves" in err[0]
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert compiled._load_extension() is None
