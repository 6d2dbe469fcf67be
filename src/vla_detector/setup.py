from glob import glob

from setuptools import find_packages, setup

package_name = "vla_detector"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/models", glob("models/detector.*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="Object detector for the latent-action context: data, training, ONNX Runtime inference node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "detector_node = vla_detector.detector_node:main",
            "vla_detector = vla_detector.cli:main",
        ],
    },
)
