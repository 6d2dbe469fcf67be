from glob import glob

from setuptools import find_packages, setup

package_name = "vla_operator"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/web", glob("web/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="The operator station: an accessible web page for the person at the joystick.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "operator_station = vla_operator.station_node:main",
        ],
    },
)
