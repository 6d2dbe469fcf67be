from setuptools import find_packages, setup

package_name = "vla_demo_recorder"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="Records demonstrations to rosbag2 MCAP bags (one per episode), recovers bags of a killed "
    "recorder and loads bags as demonstrations.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "recorder = vla_demo_recorder.recorder_node:main",
            "vla_demo_recorder = vla_demo_recorder.cli:main",
        ],
    },
)
