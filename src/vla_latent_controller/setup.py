import os
from glob import glob

from setuptools import find_packages, setup

package_name = "vla_latent_controller"

# Shipped latent-action models (models/<name>/config.json + model.safetensors) -> share/<pkg>/models/<name>
_model_dirs = sorted(d for d in glob("models/*") if os.path.isdir(d))
model_files = [
    (os.path.join("share", package_name, d), sorted(f for f in glob(d + "/*") if os.path.isfile(f)))
    for d in _model_dirs
]

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        *model_files,
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="Joystick to Panda joint velocities through learned latent actions.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "controller_node = vla_latent_controller.controller_node:main",
        ],
    },
)
