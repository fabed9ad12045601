"""ament_python package of the DSRA identification node and its bag tools."""

from glob import glob

from setuptools import find_packages, setup

# Standalone on purpose: colcon (and a per-package release) builds each package from its own
# directory, so the ament boilerplate below cannot come from a shared module.

package_name = "sysid_node"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    maintainer="sysid maintainers",
    maintainer_email="sysid-maintainers@example.com",
    description="Online structural mode identification with the recursive DSRA.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "replay = sysid_node.tools.replay:main",
            "record = sysid_node.tools.record:main",
            "sysid_node = sysid_node.entry:main",
            "offline = sysid_node.tools.offline:main",
            "validate = sysid_node.tools.validate:main",
            "envelope = sysid_node.tools.envelope:main",
        ],
    },
)
