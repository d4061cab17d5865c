"""Packaging: colcon build as a ROS 2 user would, installed executables, declared dependencies, style."""
import ast
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PKG = "additive_rsrivc_ros"
EXECUTABLES = ["rsrivc_monitor", "rsrivc_diagnose", "rsrivc_simulate", "rsrivc_replay", "rsrivc_identify",
               "rsrivc_bench"]

# import name -> (package.xml key, pip distribution name or None for ROS packages)
THIRD_PARTY = {
    "numpy": ("python3-numpy", "numpy"), "scipy": ("python3-scipy", "scipy"), "numba": ("python3-numba", "numba"),
    "yaml": ("python3-yaml", "pyyaml"), "matplotlib": ("python3-matplotlib", "matplotlib"),
    "rosbags": ("python3-rosbags-pip", "rosbags"), "mcap": ("python3-mcap-pip", "mcap"),
    "mcap_ros2": ("python3-mcap-ros2-support-pip", "mcap-ros2-support"),
}
ROS_PACKAGES = {"rclpy", "std_msgs", "sensor_msgs", "diagnostic_msgs", "std_srvs", "lifecycle_msgs",
                "rosgraph_msgs", "builtin_interfaces", "ament_index_python", "rcl_interfaces"}


def _package_imports() -> set[str]:
    names: set[str] = set()
    for path in (REPO / PKG).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != PKG and n != "setuptools"}


def test_every_third_party_import_is_declared():
    xml = (REPO / "package.xml").read_text()
    exec_deps = set(re.findall(r"<exec_depend>([^<]+)</exec_depend>", xml))
    setup_py = (REPO / "setup.py").read_text()
    requirements = (REPO / "requirements" / "requirements.txt").read_text()
    imports = _package_imports()
    unknown = imports - set(THIRD_PARTY) - ROS_PACKAGES
    assert not unknown, f"imports with no known declaration mapping (add to package.xml and setup.py): {unknown}"
    for name in imports:
        if name in ROS_PACKAGES:
            assert name in exec_deps, f"ROS package {name} is imported but not an exec_depend in package.xml"
        else:
            key, dist = THIRD_PARTY[name]
            assert key in exec_deps, f"{name}: add <exec_depend>{key}</exec_depend> to package.xml"
            assert f'"{dist}"' in setup_py, f"{name}: add {dist} to install_requires in setup.py"
            assert re.search(rf"^{re.escape(dist)}\b", requirements, re.M | re.I), f"{dist} not in requirements"


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
    expected = sorted(p.name for p in (REPO / "config").glob("*.yaml"))
    assert listing == str(expected)
