"""ament_python package setup for additive_rsrivc_ros."""
import os
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

package_name = "additive_rsrivc_ros"


def _tree(src: str, dst: str) -> list[tuple[str, list[str]]]:
    """data_files entries that install every file below ``src`` to ``dst``, keeping sub-folders."""
    out: dict[str, list[str]] = {}
    for path in sorted(glob(os.path.join(src, "**", "*"), recursive=True)):
        if os.path.isfile(path):
            rel = os.path.relpath(os.path.dirname(path), src)
            out.setdefault(os.path.normpath(os.path.join(dst, rel)), []).append(path)
    return sorted(out.items())


class BuildPyWithConfig(build_py):
    """build_py that also copies ``config/*.yaml`` (the one hand-kept copy) into the built package as
    ``additive_rsrivc_ros/data/config``, so the scenarios find their params files after a plain
    ``pip install .`` or ``colcon build`` (``sim.scenarios.config_dir``)."""

    def run(self) -> None:
        super().run()
        dst = os.path.join(self.build_lib, package_name, "data", "config")
        self.mkpath(dst)
        for path in sorted(glob("config/*.yaml")):
            self.copy_file(path, os.path.join(dst, os.path.basename(path)))


share = os.path.join("share", package_name)
setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        (share, ["package.xml"]),
        (os.path.join(share, "config"), sorted(glob("config/*.yaml"))),
        (os.path.join(share, "config", "joints"), sorted(glob("config/joints/*.yaml"))),
        (os.path.join(share, "launch"), sorted(glob("launch/*.launch.py"))),
        *_tree("bags", os.path.join(share, "bags")),
    ],
    install_requires=[
        # third-party Python modules imported by the package (ROS interfaces: see package.xml, or the extra "ros");
        # the floors are package.xml's, those of Ubuntu 24.04 (requirements/oldest.txt, tested by
        # scripts/test_oldest.sh)
        "setuptools", "numpy>=1.26", "scipy>=1.11", "numba>=0.58.1", "pyyaml>=6.0", "rosbags>=0.10.9",
    ],
    # optional fast bag reading: the MCAP bulk reader (mcap_fast.py; without it bags are read by rosbags,
    # bagio._read_fast) and the libyaml parser of rosbags' metadata (ruamel.yaml's pure-Python one otherwise)
    extras_require={
        "mcap": ["mcap", "ruamel.yaml.clib"],
        # rsrivc_fleet only (rosdistro has no dask key; the node never needs it)
        "fleet": ["dask[distributed]"],
        "test": ["pytest", "ruff", "mypy", "types-PyYAML", "mcap", "mcap-ros2-support"],
        # rsrivc_monitor without a ROS 2 installation: ROS 2 Jazzy's Python packages as wheels (rosdep users have
        # them from /opt/ros/jazzy; package.xml's exec_depends)
        "ros": ["ros-jazzy-rclpy", "ros-jazzy-common-interfaces", "ros-jazzy-rmw-fastrtps-cpp"],
    },
    cmdclass={"build_py": BuildPyWithConfig},
    zip_safe=True,
    maintainer="additive_rsrivc_ros developers",
    maintainer_email="dev@additive-rsrivc.invalid",
    description=("Online tracking and fault diagnosis of mechanical resonances with closed-loop additive "
                 "recursive SRIVC."),
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "rsrivc_monitor = additive_rsrivc_ros.node:main",
            "rsrivc_joints = additive_rsrivc_ros.joints_node:main",
            "rsrivc_diagnose = additive_rsrivc_ros.cli.diagnose:main",
            "rsrivc_simulate = additive_rsrivc_ros.cli.simulate:main",
            "rsrivc_replay = additive_rsrivc_ros.cli.replay:main",
            "rsrivc_identify = additive_rsrivc_ros.cli.identify:main",
            "rsrivc_bench = additive_rsrivc_ros.cli.bench:main",
            "rsrivc_evaluate = additive_rsrivc_ros.cli.evaluate:main",
            "rsrivc_warmup = additive_rsrivc_ros.warmup:main",
            "rsrivc_fleet = additive_rsrivc_ros.cli.fleet:main",
        ],
    },
)
