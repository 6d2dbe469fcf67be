from setuptools import find_packages, setup

package_name = "vla_study"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"vla_study": ["protocols/*.yaml", "protocols/development/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="VLA developers",
    maintainer_email="dev@vla.invalid",
    description="The paper's user study (Section 7).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "vla_study = vla_study.cli:main",
        ],
    },
)
