"""ament_python package; also installs with pip into a plain venv from PyPI alone."""

from glob import glob

from setuptools import Extension, find_packages, setup

PACKAGE = "forearm_dynamics"

# Executables: console scripts (pip) and lib/forearm_dynamics/<exe> (colcon, `ros2 run`).
EXECUTABLES = {
    "export_urdf": "forearm_dynamics.cli.export_urdf:main",
    "make_reference": "forearm_dynamics.cli.make_reference:main",
    "reproduce_paper": "forearm_dynamics.cli.reproduce_paper:main",
    "check_bag": "forearm_dynamics.cli.check_bag:main",
    "demo": "forearm_dynamics.cli.demo:main",
    "torque_node": "forearm_dynamics.nodes.torque_node:main",
    "torque_lifecycle_node": "forearm_dynamics.nodes.lifecycle:main",
    "arm_sim": "forearm_dynamics.nodes.arm_sim:main",
    "trajectory_publisher": "forearm_dynamics.nodes.trajectory_publisher:main",
    "bag_recorder": "forearm_dynamics.nodes.bag_recorder:main",
    "null_echo_node": "forearm_dynamics.nodes.null_echo_node:main",
    "bag_player": "forearm_dynamics.nodes.bag_player:main",
    "bag_torques": "forearm_dynamics.cli.bag_torques:main",
    "mot_to_bag": "forearm_dynamics.cli.mot_to_bag:main",
    "bag_export": "forearm_dynamics.cli.bag_export:main",
    "arm_viz": "forearm_dynamics.nodes.arm_viz:main",
    "bag_viz": "forearm_dynamics.cli.bag_viz:main",
    "muscle_node": "forearm_dynamics.nodes.muscle_node:main",
    "bag_muscles": "forearm_dynamics.cli.bag_muscles:main",
}

# What the three extensions share for a call on arrays (get_vector, bound_call): one header,
# on their include path.
BUFFERS = f"{PACKAGE}/_buffers.h"

# The Kalman filter's per-sample arithmetic in C (estimation/kalman_step.py says why), and its
# practice filter's (estimation/practice_step.py);
# optional: without a C compiler the install goes on and the filter runs numpy's way.
# -ffp-contract=off: no fused multiply-add, every product and sum rounded as numpy rounds it.
KALMAN_STEP = Extension(f"{PACKAGE}.estimation._kalman_step",
                        [f"{PACKAGE}/estimation/_kalman_step.c",
                         f"{PACKAGE}/estimation/_practice_step.c"],
                        depends=[f"{PACKAGE}/estimation/_kalman_step.h", BUFFERS],
                        include_dirs=[PACKAGE],
                        extra_compile_args=["-O2", "-ffp-contract=off"], optional=True)

# The noise estimator's per-sample store in C (estimation/noise_step.py says why); optional
# in the same way.
NOISE_STEP = Extension(f"{PACKAGE}.estimation._noise_step",
                       [f"{PACKAGE}/estimation/_noise_step.c",
                        f"{PACKAGE}/estimation/_noise_evaluations.c"],
                       depends=[f"{PACKAGE}/estimation/_noise_step.h", BUFFERS],
                       include_dirs=[PACKAGE],
                       extra_compile_args=["-O2", "-ffp-contract=off"], optional=True)

# The muscle node's arithmetic around the QP in C (muscles/muscle_step.py says why); optional
# in the same way.
MUSCLE_STEP = Extension(f"{PACKAGE}.muscles._muscle_step", [f"{PACKAGE}/muscles/_muscle_step.c"],
                        depends=[BUFFERS], include_dirs=[PACKAGE],
                        extra_compile_args=["-O2", "-ffp-contract=off"], optional=True)

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "benchmarks", "benchmarks.*"]),
    ext_modules=[KALMAN_STEP, NOISE_STEP, MUSCLE_STEP],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml") + glob("config/*.json")),
        (f"share/{PACKAGE}/config/nodes", glob("config/nodes/*.yaml")),  # node parameters
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),  # ros2 launch (docs/ros.md)
        # closed_loop.launch.py runs the example (its report module beside it)
        (f"share/{PACKAGE}/examples", ["examples/closed_loop.py", "examples/closed_loop_report.py"]),
    ],
    package_data={PACKAGE: ["data/*"]},
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.26",
        "pin>=3.0",
        "pyyaml>=6",
        "scipy>=1.11",
        "threadpoolctl>=3.1",  # one BLAS thread in the nodes (nodes/common.py run())
        "mcap>=1.5",  # Writer.flush() (public) first in 1.5.0
        "zstandard>=0.20",  # bag/augment.py (bag_viz) recompresses chunks; mcap needs it too
        "ros-jazzy-rclpy",
        "ros-jazzy-rmw-fastrtps-cpp",
        "ros-jazzy-sensor-msgs",
        "ros-jazzy-std-msgs",
        "ros-jazzy-diagnostic-msgs",
        "ros-jazzy-builtin-interfaces",
        "ros-jazzy-rcl-interfaces",
        "ros-jazzy-rosgraph-msgs",
        "ros-jazzy-visualization-msgs",  # arm_viz, bag_viz: MarkerArray
        # check_bag --html: its offline JavaScript bundle makes the report one file that opens
        # without a network; pure Python (+ narwhals, packaging), so required, not an extra
        "plotly>=6",
        "daqp>=0.7",  # muscles/static_opt.py: the QP of the static optimisation (MIT)
    ],
    extras_require={
        "plots": ["matplotlib>=3.7"],
        "reference": ["opensim==4.6"],
        # python -m forearm_dynamics.muscles.fit: re-derives the shipped muscle model
        "muscles-fit": ["mujoco==3.17.0", "myo-sim==0.2.4"],
        "test": ["pytest>=8", "hypothesis>=6.100", "rosbags>=0.10", "ruff>=0.5",
                 "colcon-common-extensions", "colcon-ros"],
    },
    zip_safe=True,
    maintainer="forearm_dynamics developers",
    maintainer_email="dev@forearm-dynamics.invalid",
    description="Real-time hand-and-forearm inverse dynamics for prosthesis controllers",
    license="BSD-3-Clause",
    entry_points={"console_scripts": [f"{k} = {v}" for k, v in EXECUTABLES.items()]},
)
