from setuptools import find_packages, setup

package_name = "vla_camera"

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
    description=(
        "Publishes camera frames (webcam, video file or image folder) as sensor_msgs/Image with CameraInfo."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "camera_node = vla_camera.camera_node:main",
        ],
    },
)
