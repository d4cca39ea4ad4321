#!/bin/sh
# Generate and install tf2_msgs (TFMessage only) into a venv from the rosidl generator packages on PyPI.
#
# tf2_msgs has no PyPI wheel, so without a full ROS install the node cannot read /tf or /tf_static, nor
# broadcast the plane's transform. The rosidl generators ARE on PyPI: this script installs them (the
# `tf2` extra of setup.py), writes the one message tf2_msgs/TFMessage (geometry_msgs/TransformStamped[]
# transforms, the very definition of ROS 2 Jazzy's tf2_msgs), and builds it with CMake and a C compiler
# into the venv (libraries in VENV/lib, the Python package in site-packages), like colcon would.
#
# Usage: scripts/build_tf2_msgs.sh [VENV]   (default .venv). Needs cmake and a C/C++ compiler.
# Exit code 0 when tf2_msgs imports afterwards; otherwise a line saying why (the node runs without it).
set -eu
VENV=$(cd "${1:-.venv}" && pwd)
PY="$VENV/bin/python"
if "$PY" -c 'import tf2_msgs.msg' 2>/dev/null; then
    echo "tf2_msgs: already importable in $VENV"
    exit 0
fi
for tool in cmake cc c++; do
    command -v "$tool" >/dev/null 2>&1 || { echo "tf2_msgs: not generated: '$tool' not found (apt-get install cmake g++)"; exit 1; }
done
HERE=$(cd "$(dirname "$0")/.." && pwd)
"$PY" -m pip install --quiet -e "$HERE[tf2]" || { echo "tf2_msgs: not generated: the rosidl generator packages did not install"; exit 1; }
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK/src/msg" "$WORK/build"
echo 'geometry_msgs/TransformStamped[] transforms' > "$WORK/src/msg/TFMessage.msg"
cat > "$WORK/src/package.xml" <<'XML'
<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.36.0</version>
  <description>tf2_msgs/TFMessage generated for tissue_sim_ros (no PyPI wheel of tf2_msgs exists)</description>
  <maintainer email="tissue-sim@example.org">tissue_sim_ros developers</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
XML
cat > "$WORK/src/CMakeLists.txt" <<'CMAKE'
cmake_minimum_required(VERSION 3.16)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(geometry_msgs REQUIRED)
find_package(Python3 REQUIRED COMPONENTS Interpreter Development)
# the PyPI wheels' exported targets name the wheel builder's Python headers: use this Python's
foreach(pkg builtin_interfaces std_msgs geometry_msgs service_msgs)
  if(TARGET ${pkg}::${pkg}__rosidl_generator_py)
    set_target_properties(${pkg}::${pkg}__rosidl_generator_py PROPERTIES
      INTERFACE_INCLUDE_DIRECTORIES "${Python3_INCLUDE_DIRS}")
  endif()
endforeach()
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_package()
CMAKE
export PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV"
cd "$WORK/build"
if ! cmake ../src -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$PY" \
        -DBUILD_TESTING=OFF > "$WORK/cmake.log" 2>&1 \
   || ! cmake --build . -j 2 > "$WORK/build.log" 2>&1 || ! cmake --install . > "$WORK/install.log" 2>&1; then
    tail -15 "$WORK"/*.log
    echo "tf2_msgs: not generated: the CMake build failed (log above)"
    exit 1
fi
if "$PY" -c 'from tf2_msgs.msg import TFMessage' 2>/dev/null; then
    echo "tf2_msgs: generated and installed into $VENV"
else
    echo "tf2_msgs: built, but does not import in $VENV"
    exit 1
fi
