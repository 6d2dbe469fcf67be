from setuptools import find_packages, setup

package_name = "vla_latent_controller"

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
    description="Joystick to Panda joint velocities through learned latent actions.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "controller_node = vla_latent_controller.controller_node:main",
            "sim_teleoperator = vla_latent_controller.sim_teleoperator_node:main",
            "joy_node = vla_latent_controller.joy_node:main",
            "vla_latent_controller = vla_latent_controller.cli:main",
        ],
    },
)
