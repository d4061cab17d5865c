"""ament_python package setup for additive_rsrivc_ros."""
import os
from glob import glob

from setuptools import find_packages, setup

package_name = "additive_rsrivc_ros"


def _tree(src: str, dst: str) -> list[tuple[str, list[str]]]:
    """data_files entries that install every file below ``src`` to ``dst``, keeping sub-folders."""
    out: dict[str, list[str]] = {}
    for path in sorted(glob(os.path.join(src, "**", "*"), recursive=True)):
        if os.path.isfile(path):
            rel = os.path.relpath(os.path.dirname(path), src)
            out.setdefault(os.path.normpath(os.path.join(dst, rel)), []).append(path)
    return sorted(out.items())


share = os.path.join("share", package_name)
setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        (share, ["package.xml"]),
        (os.path.join(share, "config"), sorted(glob("config/*.yaml"))),
        *_tree("bags", os.path.join(share, "bags")),
    ],
    install_requires=[
        # third-party Python modules imported by the package (ROS interfaces: see package.xml)
        "setuptools", "numpy", "scipy", "numba", "pyyaml", "matplotlib", "rosbags", "mcap", "mcap-ros2-support",
    ],
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
            "rsrivc_diagnose = additive_rsrivc_ros.cli.diagnose:main",
            "rsrivc_simulate = additive_rsrivc_ros.cli.simulate:main",
            "rsrivc_replay = additive_rsrivc_ros.cli.replay:main",
            "rsrivc_identify = additive_rsrivc_ros.cli.identify:main",
            "rsrivc_bench = additive_rsrivc_ros.cli.bench:main",
            "rsrivc_evaluate = additive_rsrivc_ros.cli.evaluate:main",
        ],
    },
)
