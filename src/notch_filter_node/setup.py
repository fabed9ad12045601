"""ament_python package of the adaptive notch filter node."""

from glob import glob

from setuptools import find_packages, setup

# Standalone on purpose: colcon (and a per-package release) builds each package from its own
# directory, so the ament boilerplate below cannot come from a shared module.

package_name = "notch_filter_node"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/layouts", glob("layouts/*")),
    ],
    install_requires=["setuptools"],
    maintainer="sysid maintainers",
    maintainer_email="sysid-maintainers@example.com",
    description="Adaptive notch filter bank following identified structural modes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "notch_filter_node = notch_filter_node.node:main",
        ],
    },
)
