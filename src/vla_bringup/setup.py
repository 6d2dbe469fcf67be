from glob import glob

from setuptools import find_packages, setup

package_name = "vla_bringup"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.yaml")),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description=(
        "Launch files, shared parameters and the `vla` tool "
        "(ros2 run / ros2 launch for machines without ros2cli)."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "vla = vla_bringup.cli:main",
            "demo_talker = vla_bringup.demo_talker:main",
            "demo_listener = vla_bringup.demo_listener:main",
        ],
    },
)
