import os
from glob import glob

from setuptools import setup

package_name = "vla_bringup"


def panda_urdf() -> list[str]:
    """example-robot-data's Panda URDF (the one vla_common's kinematics and /robot_description use),
    installed as share/vla_bringup/urdf/panda.urdf for robot_state_publisher (use_tf:=true)."""
    import example_robot_data  # a build dependency (rosdep key example-robot-data)

    urdf = "panda_description/urdf/panda.urdf"
    path = os.path.join(example_robot_data.getModelPath(urdf), urdf)
    return [os.path.relpath(path, os.path.dirname(os.path.abspath(__file__)))]  # setuptools: relative

setup(
    name=package_name,
    version="0.1.0",
    packages=[],
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.yaml")),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/dds", glob("config/dds/*")),
        ("share/" + package_name + "/urdf", panda_urdf()),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="Launch files and parameter files of the node graph (nothing else).",
    license="Apache-2.0",
)
