"""Plain-pip installation of the ROS-free core library and its command-line tools.

`pip install .` gives the elastic models, solvers, bundles, CAN codec and the offline matrix
tool without ROS. The ROS 2 nodes need rclpy and the package's messages, which the CMake build
(colcon on a robot, `make setup` here) provides.
"""

from pathlib import Path

from setuptools import find_packages, setup

setup(
    name="tactile_contact",
    version="0.1.0",
    description="Contact shapes from capacitive robot skin (ROBOSKIN / iCub) over CAN",
    long_description=Path(__file__).with_name("README.md").read_text(encoding="utf-8"),
    long_description_content_type="text/markdown",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(include=["tactile_contact", "tactile_contact.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/tactile_contact"]),
        ("share/tactile_contact", ["package.xml"]),
    ],
    install_requires=[
        "numpy>=1.24",
        "scipy>=1.10",
        "pyyaml>=6",
        "python-can>=4.3",
        "tqdm>=4.60",
        "threadpoolctl>=3.1",
        # (the round fit, the detector, the fusion and the idle gate are compiled kernels;
        # tactile-contact-build imports them)
        "numba>=0.59",
    ],
    extras_require={
        "demo": ["matplotlib>=3.7"],
        "bags": ["rosbags>=0.10"],
        "test": ["pytest>=8", "hypothesis>=6.100", "ruff>=0.6", "ContactMechanics>=1.8"],
    },
    entry_points={
        "console_scripts": [
            "tactile-contact-build = tactile_contact.offline.build:main",
            "tactile-contact = tactile_contact.ros.cli:main",
            "tactile-contact-calibrate = tactile_contact.offline.calibrate:main",
            "tactile-contact-presses = tactile_contact.offline.presses:main_presses",
            "tactile-contact-import-icub = tactile_contact.offline.icub.cli:main",
        ],
    },
)
