"""Packaging: colcon build as a ROS 2 user would, installed executables, declared dependencies, style."""
import ast
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
PKG = "additive_rsrivc_ros"
EXECUTABLES = ["rsrivc_monitor", "rsrivc_diagnose", "rsrivc_simulate", "rsrivc_replay", "rsrivc_identify",
               "rsrivc_bench", "rsrivc_fleet", "rsrivc_warmup", "rsrivc_joints"]

# import name -> (package.xml key, pip distribution name or None for ROS packages)
THIRD_PARTY = {
    "numpy": ("python3-numpy", "numpy"), "scipy": ("python3-scipy", "scipy"), "numba": ("python3-numba", "numba"),
    "yaml": ("python3-yaml", "pyyaml"),
    "rosbags": ("python3-rosbags-pip", "rosbags"),
}
# optional imports (setup.py extra, requirements.txt; no rosdep key): import name -> pip distribution
OPTIONAL = {"mcap": "mcap", "dask": "dask"}   # import name -> distribution of a setup.py extra
ROS_PACKAGES = {"rclpy", "std_msgs", "sensor_msgs", "diagnostic_msgs", "std_srvs", "lifecycle_msgs",
                "rosgraph_msgs", "builtin_interfaces", "rcl_interfaces"}
LAUNCH_IMPORTS = {"launch", "launch_ros", "ament_index_python"}

# Every <*_depend> key of package.xml, checked by hand against ros/rosdistro (commit 8468e88c, 2026-08-22):
# rosdep keys in rosdep/python.yaml, ROS packages in jazzy/distribution.yaml (line of the key or package entry).
# A new dependency needs a key found there; docs/DEPENDENCIES.md lists the same table.
ROSDEP_KEYS = {
    "rclpy": "jazzy/distribution.yaml:8959 (repository rclpy)",
    "std_msgs": "jazzy/distribution.yaml:1827 (common_interfaces)",
    "sensor_msgs": "jazzy/distribution.yaml:1824 (common_interfaces)",
    "diagnostic_msgs": "jazzy/distribution.yaml:1821 (common_interfaces)",
    "std_srvs": "jazzy/distribution.yaml:1828 (common_interfaces)",
    "lifecycle_msgs": "jazzy/distribution.yaml:8853 (rcl_interfaces)",
    "rosgraph_msgs": "jazzy/distribution.yaml:8855 (rcl_interfaces)",
    "builtin_interfaces": "jazzy/distribution.yaml:8851 (rcl_interfaces)",
    "rcl_interfaces": "jazzy/distribution.yaml:8854 (rcl_interfaces)",
    "ament_index_python": "jazzy/distribution.yaml:359 (ament_index)",
    "launch": "jazzy/distribution.yaml:5101 (launch)",
    "launch_ros": "jazzy/distribution.yaml:5169 (launch_ros)",
    "diagnostic_aggregator": "jazzy/distribution.yaml:2403 (diagnostics)",
    "python3-numpy": "rosdep/python.yaml:5923",
    "python3-scipy": "rosdep/python.yaml:8194",
    "python3-numba": "rosdep/python.yaml:5920",
    "python3-yaml": "rosdep/python.yaml:9553",
    "python3-rosbags-pip": "rosdep/python.yaml:7996",
    "python3-pytest": "rosdep/python.yaml:7446",
    "python3-ruff-pip": "rosdep/python.yaml:8114",
    "python3-mypy": "rosdep/python.yaml:5749",
    "mcap-ros2-support": "rosdep/python.yaml:328",
}
TEST_DEPENDS = {"python3-pytest", "python3-ruff-pip", "mcap-ros2-support", "python3-mypy"}


def _package_imports(paths=None) -> set[str]:
    names: set[str] = set()
    for path in paths or (REPO / PKG).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != PKG and n != "setuptools"}


def _depends(xml: str, tag: str = r"\w*depend") -> set[str]:
    """The keys of every ``<tag>`` element (default: all ``*_depend`` and ``depend``)."""
    return {key for _, key in re.findall(rf"<({tag})(?:\s[^>]*)?>([^<]+)</\1>", xml)}


def _floors_xml(xml: str) -> dict[str, str]:
    """``version_gte`` of each package.xml key that has one."""
    return dict((k, v) for v, k in re.findall(r'<\w*depend version_gte="([^"]+)">([^<]+)</', xml))


def _floors_setup(setup_py: str) -> dict[str, str]:
    """``name>=floor`` of each install_requires entry that has one."""
    block = re.search(r"install_requires=\[(.*?)\]", setup_py, re.S).group(1)
    return {n.lower(): v for n, v in re.findall(r'"([\w.-]+)>=([\w.]+)"', block)}


def test_every_third_party_import_is_declared():
    xml = (REPO / "package.xml").read_text()
    exec_deps = _depends(xml, "exec_depend")
    setup_py = (REPO / "setup.py").read_text()
    requirements = (REPO / "requirements" / "requirements.txt").read_text()
    imports = _package_imports()
    unknown = imports - set(THIRD_PARTY) - set(OPTIONAL) - ROS_PACKAGES
    assert not unknown, f"imports with no known declaration mapping (add to package.xml and setup.py): {unknown}"
    for name in imports:
        if name in ROS_PACKAGES:
            assert name in exec_deps, f"ROS package {name} is imported but not an exec_depend in package.xml"
        elif name in OPTIONAL:
            assert re.search(rf'extras_require=\{{[^}}]*"{re.escape(OPTIONAL[name])}[\["]', setup_py, re.S), \
                f"{name}: not a setup.py extra"
        else:
            key, dist = THIRD_PARTY[name]
            assert key in exec_deps, f"{name}: add <exec_depend>{key}</exec_depend> to package.xml"
            assert re.search(rf'"{re.escape(dist)}(>=[\w.]+)?"', setup_py), f"{name}: add {dist} to install_requires"
        dist = OPTIONAL.get(name) or THIRD_PARTY.get(name, (None, None))[1]
        if dist:
            assert re.search(rf"^{re.escape(dist)}\b", requirements, re.M | re.I), f"{dist} not in requirements"


def test_declared_floors_agree_and_are_the_tested_oldest_stack():
    """setup.py's floors, package.xml's version_gte and requirements/oldest.txt (what scripts/test_oldest.sh installs
    and runs the smoke subset on) name the same version of each third-party dependency."""
    xml_floors = _floors_xml((REPO / "package.xml").read_text())
    setup_floors = _floors_setup((REPO / "setup.py").read_text())
    pins = {n.lower(): v for n, v in re.findall(r"^([\w.-]+)==([\w.]+)", (REPO / "requirements" / "oldest.txt")
                                                   .read_text(), re.M)}
    for key, dist in THIRD_PARTY.values():
        floor = setup_floors.get(dist)
        assert floor, f"setup.py: {dist} has no floor (name>=version)"
        assert xml_floors.get(key) and floor.startswith(xml_floors[key]), (key, xml_floors.get(key), floor)
        assert pins.get(dist, "").startswith(floor), f"requirements/oldest.txt: {dist} {pins.get(dist)}, floor {floor}"


def test_dependency_keys_are_the_checked_rosdep_keys():
    """rosdep install must resolve every key: package.xml holds exactly the keys checked in rosdistro."""
    xml = (REPO / "package.xml").read_text()
    assert _depends(xml) == set(ROSDEP_KEYS), "a key was added or removed: check it in rosdistro and record it"
    assert _depends(xml, "test_depend") == TEST_DEPENDS
    assert not _depends(xml, "exec_depend") & TEST_DEPENDS, "test-only packages must be <test_depend>"
    table = (REPO / "docs" / "DEPENDENCIES.md").read_text()
    for key, source in ROSDEP_KEYS.items():
        assert f"`{key}`" in table and source.split(" ")[0] in table, f"{key} missing from docs/DEPENDENCIES.md"


def test_optional_mcap_is_imported_only_inside_functions():
    """No module imports mcap at import time, so the package works without it (bagio then uses rosbags)."""
    for path in (REPO / PKG).rglob("*.py"):
        for node in ast.parse(path.read_text(), str(path)).body:
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n.split(".")[0] in OPTIONAL for n in names), f"{path}: module-level import of {names}"


def test_bags_are_read_by_rosbags_when_mcap_is_not_installed(tmp_path, monkeypatch):
    """With ``import mcap`` failing, read_signals takes the rosbags path and returns the same samples."""
    from additive_rsrivc_ros.io import bagio
    from additive_rsrivc_ros.sim.scenarios import build

    data = build("beam", duration_s=1.0, seed=3)
    bag = data.write_bag(tmp_path / "bag")
    fast = bagio.read_signals(bag, data.config)
    calls = []
    real_read_fast = bagio._read_fast
    monkeypatch.setattr(bagio, "_read_fast", lambda *a: calls.append(real_read_fast(*a)) or calls[-1])
    for mod in ["mcap", *(m for m in sys.modules if m.startswith("mcap."))]:
        monkeypatch.setitem(sys.modules, mod, None)  # `import mcap`, `from mcap.x import y` raise ImportError
    slow = bagio.read_signals(bag, data.config)
    assert calls == [None], "the fast path ran although mcap is not importable"
    assert slow.n == fast.n == data.y.size
    for f in ("t", "r", "u", "y"):
        np.testing.assert_array_equal(getattr(slow, f), getattr(fast, f), err_msg=f)


def test_package_xml_is_format_3_ament_python():
    xml = (REPO / "package.xml").read_text()
    assert '<package format="3">' in xml and "<build_type>ament_python</build_type>" in xml
    assert "<test_depend>python3-pytest</test_depend>" in xml


def test_style_ruff_clean():
    res = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(REPO)],
                         capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 0, res.stdout + res.stderr


def _copy_sources(dst: Path) -> None:
    """Copy the tracked and untracked-but-not-ignored files, i.e. what a clone would contain."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, capture_output=True,
                           text=True, check=True).stdout.split()
    for rel in files:
        src = REPO / rel
        if src.is_file():
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / rel)


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory) -> Path:
    colcon = str(Path(sys.executable).parent / "colcon")
    if not Path(colcon).exists():
        pytest.fail("colcon is not installed in the environment (scripts/bootstrap.sh installs it)")
    ws = tmp_path_factory.mktemp("colcon_ws")
    _copy_sources(ws / "src" / PKG)
    env = {k: v for k, v in os.environ.items() if not k.startswith("COLCON")}
    res = subprocess.run([colcon, "build", "--event-handlers", "console_direct-"], cwd=ws, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return ws / "install"


def _sourced(install: Path, command: str) -> subprocess.CompletedProcess:
    script = f'source "{install}/setup.bash" && {command}'
    return subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120)


def test_colcon_build_installs_executables_where_ros2_run_looks(colcon_install):
    libdir = colcon_install / PKG / "lib" / PKG
    for exe in EXECUTABLES:
        assert (libdir / exe).is_file(), f"{exe} not installed to lib/{PKG}/ (ros2 run would not find it)"
    res = _sourced(colcon_install, f'"{libdir}/rsrivc_monitor" --help')
    assert res.returncode == 0, res.stderr
    assert "usage" in res.stdout.lower() and "--ros-args" in res.stdout


def test_ament_index_finds_installed_config(colcon_install):
    code = ("from ament_index_python.packages import get_package_share_directory as g; "
            f"import os; d = g('{PKG}'); print(d); print(sorted(os.listdir(os.path.join(d, 'config'))))")
    res = _sourced(colcon_install, f'"{sys.executable}" -c "{code}"')
    assert res.returncode == 0, res.stderr
    share, listing = res.stdout.splitlines()[:2]
    assert Path(share).resolve() == (colcon_install / PKG / "share" / PKG).resolve()
    expected = sorted(p.name for p in (REPO / "config").iterdir() if p.suffix == ".yaml" or p.is_dir())  # + joints/
    assert listing == str(expected)


# ---------------------------------------------------------------------------------------------------- launch files
# `launch` and `launch_ros` are not installable here (no PyPI wheels): the files are checked by parsing them;
# `ros2 launch` itself is not run (README says so).
LAUNCH_ARGUMENTS = {"monitor.launch.py": {"params_file", "namespace", "use_sim_time", "autostart", "log_level"},
                    "multi_axis.launch.py": {"axes", "params_file", "use_sim_time", "autostart", "log_level",
                                             "aggregator", "modes"},
                    "joints.launch.py": {"params_file", "joints", "count", "namespace", "use_sim_time", "autostart",
                                         "log_level"}}
# nodes of other packages a launch file may start (package -> executable); each package is an exec_depend
OTHER_LAUNCHED = {"diagnostic_aggregator": "aggregator_node"}


def _launch_tree(name: str) -> ast.Module:
    return ast.parse((REPO / "launch" / name).read_text(), name)


def _module_constants(tree: ast.Module) -> dict:
    """Module-level ``NAME = <literal>`` assignments."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                out[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    return out


def _calls(tree: ast.Module, func: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == func]


def _value(node: ast.expr, consts: dict):
    """A literal argument, or the value of the module constant it names."""
    return consts[node.id] if isinstance(node, ast.Name) else ast.literal_eval(node)


def _console_scripts() -> set[str]:
    return set(re.findall(r'"(\w+) = additive_rsrivc_ros[\w.]*:main"', (REPO / "setup.py").read_text()))


@pytest.mark.parametrize("name", sorted(LAUNCH_ARGUMENTS))
def test_launch_file_declares_and_uses_its_arguments(name):
    tree = _launch_tree(name)
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    declared = {_value(c.args[0], {}) for c in _calls(tree, "DeclareLaunchArgument")}
    used = {_value(c.args[0], {}) for c in _calls(tree, "LaunchConfiguration")}
    assert declared >= LAUNCH_ARGUMENTS[name], f"missing arguments: {LAUNCH_ARGUMENTS[name] - declared}"
    assert used == declared, f"declared but unused {declared - used}, used but undeclared {used - declared}"
    imports = _package_imports([REPO / "launch" / name])
    exec_deps = _depends((REPO / "package.xml").read_text(), "exec_depend")
    assert imports <= LAUNCH_IMPORTS <= exec_deps, f"launch imports {imports} must be exec_depends"


@pytest.mark.parametrize("name", sorted(LAUNCH_ARGUMENTS))
def test_launch_file_starts_an_installed_executable_with_existing_params(name):
    from additive_rsrivc_ros.config import DEFAULT_NODE_NAME
    from additive_rsrivc_ros.joint_params import JOINT_GROUP_NODE_NAME

    tree = _launch_tree(name)
    consts = _module_constants(tree)
    nodes = _calls(tree, "LifecycleNode") + _calls(tree, "Node")
    assert nodes, "no node action"
    exec_deps = _depends((REPO / "package.xml").read_text(), "exec_depend")
    for call in nodes:
        kw = {k.arg: k.value for k in call.keywords}
        package, executable = _value(kw["package"], consts), _value(kw["executable"], consts)
        if package != PKG:
            assert OTHER_LAUNCHED.get(package) == executable and package in exec_deps, (package, executable)
            continue
        assert executable in _console_scripts() and executable in EXECUTABLES, executable
    assert consts["DEFAULT_NODE_NAME"] == (JOINT_GROUP_NODE_NAME if consts["EXECUTABLE"] == "rsrivc_joints"
                                           else DEFAULT_NODE_NAME)
    yamls = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and str(n.value).endswith(".yaml")}
    assert yamls, "no default params file named"
    for y in yamls:
        assert (REPO / "config" / y).is_file(), f"{name} names config/{y}, which does not exist"


def test_colcon_installs_launch_files_and_their_params(colcon_install):
    share = colcon_install / PKG / "share" / PKG
    for name in LAUNCH_ARGUMENTS:
        assert (share / "launch" / name).read_text() == (REPO / "launch" / name).read_text()
        tree = _launch_tree(name)
        for y in {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and str(n.value).endswith(".yaml")}:
            assert (share / "config" / y).is_file(), f"config/{y} (named by {name}) is not installed"


def test_colcon_installed_package_finds_its_params_files(colcon_install):
    """The colcon-installed package (source tree off the path) reads the params copy installed inside it."""
    code = "from additive_rsrivc_ros.sim import scenarios as s; print(s.__file__); print(s.config_dir())"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    res = subprocess.run(["bash", "-c", f'source "{colcon_install}/setup.bash" && "{sys.executable}" -c "{code}"'],
                         capture_output=True, text=True, timeout=120, env=env, cwd=colcon_install)
    assert res.returncode == 0, res.stderr
    module, cfg = map(Path, res.stdout.splitlines()[:2])
    assert module.is_relative_to(colcon_install), f"imported {module}, not the colcon install"
    assert cfg == module.parents[1] / "data" / "config"
    assert sorted(p.name for p in cfg.glob("*.yaml")) == sorted(p.name for p in (REPO / "config").glob("*.yaml"))


def test_multi_axis_params_reach_each_namespaced_node_through_rcl():
    """rcl (not our YAML reader) applies the shared section to both axes and the axis2 section to axis2 only."""
    import rclpy
    from rclpy.node import Node

    from additive_rsrivc_ros.config import DEFAULT_NODE_NAME

    consts = _module_constants(_launch_tree("multi_axis.launch.py"))
    assert consts["AXES"] == ("axis1", "axis2")
    ctx = rclpy.Context()
    rclpy.init(args=["--ros-args", "--params-file", str(REPO / "config" / "two_axes.yaml")], context=ctx)
    try:
        got = {}
        for axis in consts["AXES"]:
            node = Node(DEFAULT_NODE_NAME, namespace=axis, context=ctx,
                        automatically_declare_parameters_from_overrides=True)
            got[axis] = {k: p.value for k, p in node._parameters.items()}
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    for axis, params in got.items():
        assert params.get("loop_rate_hz") == 4096.0 and params.get("reference.topic") == "reference", axis
    assert list(got["axis1"]["modes.natural_frequency_hz"]) == [3.2487, 32.972]
    assert list(got["axis2"]["modes.natural_frequency_hz"]) == [3.2487, 30.0]


# ------------------------------------------------------------------------------------------ plain pip install
def test_pip_install_into_a_fresh_venv_runs_simulate(tmp_path):
    """``pip install .`` (a wheel build, not editable) into a new venv; rsrivc_simulate finds its params files.

    The venv sees the dependencies of the project venv through a .pth line (no downloads, --no-index), but not its
    editable install of the package (the project venv's .pth files are not processed). NUMBA_DISABLE_JIT keeps the
    first run short: this test is about installation; the compiled numerics are tested from the source tree.
    """
    from additive_rsrivc_ros.io.bagio import read_signals
    from additive_rsrivc_ros.sim.scenarios import build

    src, venv = tmp_path / "src", tmp_path / "venv"
    _copy_sources(src)
    subprocess.run([sys._base_executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    purelib = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    deps = subprocess.run([sys.executable, "-c", "import numpy, os; print(os.path.dirname(os.path.dirname("
                           "numpy.__file__)))"], capture_output=True, text=True, check=True).stdout.strip()
    Path(purelib, "project_venv_deps.pth").write_text(deps + "\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    res = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--no-index",
                          "--no-build-isolation", "-q", str(src)], capture_output=True, text=True, env=env,
                         timeout=300)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    shutil.rmtree(src)  # nothing may come from the source tree any more
    installed = Path(purelib) / PKG
    assert sorted(p.name for p in (installed / "data" / "config").glob("*.yaml")) == sorted(
        p.name for p in (REPO / "config").glob("*.yaml"))
    share = venv / "share" / PKG
    assert (share / "package.xml").is_file() and {p.name for p in (share / "launch").glob("*.py")} == set(
        LAUNCH_ARGUMENTS)
    out = tmp_path / "bag"
    res = subprocess.run([str(venv / "bin" / "rsrivc_simulate"), "--scenario", "beam", "--duration", "2", "--out",
                          str(out)], capture_output=True, text=True, env={**env, "NUMBA_DISABLE_JIT": "1"},
                         cwd=tmp_path, timeout=300)
    assert res.returncode == 0 and res.stderr == "", res.stdout + res.stderr
    assert f"params {installed / 'data' / 'config' / 'beam.yaml'}" in res.stdout, res.stdout
    data = build("beam", duration_s=2.0, seed=0)
    sig = read_signals(out, data.config)
    assert sig.n == data.y.size == 8192
    # same scenario and seed: equal up to the rounding of interpreted vs compiled arithmetic
    np.testing.assert_allclose(sig.y, data.y, rtol=0, atol=1e-12 * np.max(np.abs(data.y)))
