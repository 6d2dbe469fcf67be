from glob import glob

from setuptools import find_packages, setup

package_name = "vla_evaluation"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="Evaluation.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim_teleoperator = vla_evaluation.sim_teleoperator_node:main",
            "vla_evaluation = vla_evaluation.cli:main",
        ],
    },
)
