"""``tf2_msgs/msg/TFMessage`` in a virtual environment whose ROS 2 comes from PyPI.

The node publishes ``map → odom`` on ``/tf`` as AMCL does, which takes ``tf2_msgs``. A robot's ROS 2
install has it; the PyPI wheels of ROS 2 Kilted (the ``ros2`` extra) do not. This module builds
it the way ROS builds any message package (``rosidl_generate_interfaces`` with the wheels' own
generators, CMake and the C compiler) and installs it into the running environment::

    python -m fusion.ros2.tf2_msgs

The message is ROS 2's own definition, so its type hash, and every subscriber of ``/tf``, agree.
Only ``TFMessage`` is built: the package's other interfaces (``TF2Error``, ``FrameGraph``,
``LookupTransform``) are tf2's services and actions, which the node does not use.

The wheels' exported CMake targets name the include folders of the machine that built them
(``/opt/python/cp3XX-cp3XX/...``); those paths are pointed at this environment's Python and NumPy
before CMake runs, in this environment's ``share/*/cmake`` files only.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

TF_MESSAGE = "geometry_msgs/TransformStamped[] transforms\n"
"""tf2_msgs/msg/TFMessage.msg, as in ROS 2 (geometry2)."""

BUILD_REQUIREMENTS = [
    "ros-kilted-rosidl-default-generators==1.7.*",
    "ros-kilted-ament-cmake==2.7.*",
    "ros-kilted-ament-cmake-include-directories==2.7.*",
    "ros-kilted-ament-cmake-ros-core==0.14.*",
    "ros-kilted-rosidl-core-generators==0.3.*",
    "ros-kilted-ament-package==0.17.*",
    "catkin-pkg>=1.0",
]
"""What the build needs beyond the node's own wheels (the generators and CMake's ament)."""

PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.43.0</version>
  <description>tf2_msgs/msg/TFMessage, built for houghloc's ROS 2 node</description>
  <maintainer email="houghloc@example.org">houghloc</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""

CMAKE_LISTS = """cmake_minimum_required(VERSION 3.20)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""

_BUILD_MACHINE = re.compile(r"/opt/python/cp\d+-cp\d+t?/(include/python3\.\d+t?|"
                            r"lib/python3\.\d+t?/site-packages/numpy/_core/include)")


class BuildError(RuntimeError):
    """The message could not be built here; the text says what is missing."""


def available() -> bool:
    """Whether ``tf2_msgs.msg.TFMessage`` can be imported in this environment."""
    try:
        return importlib.util.find_spec("tf2_msgs.msg") is not None
    except ModuleNotFoundError:
        return False


def build(prefix: Path | None = None, quiet: bool = True) -> None:
    """Build ``tf2_msgs`` and install it into ``prefix`` (default: this environment)."""
    prefix = Path(prefix or sys.prefix)
    for tool in ("cmake", "cc", "make"):
        if shutil.which(tool) is None:
            raise BuildError(f"building tf2_msgs needs {tool} (install CMake and a C compiler)")
    _run([sys.executable, "-m", "pip", "install", "--quiet", *BUILD_REQUIREMENTS], quiet)
    _use_this_environment(prefix)
    with tempfile.TemporaryDirectory(prefix="tf2_msgs-") as tmp:
        source, build_dir = Path(tmp) / "tf2_msgs", Path(tmp) / "build"
        (source / "msg").mkdir(parents=True)
        (source / "msg" / "TFMessage.msg").write_text(TF_MESSAGE)
        (source / "package.xml").write_text(PACKAGE_XML)
        (source / "CMakeLists.txt").write_text(CMAKE_LISTS)
        build_dir.mkdir()
        env = {"PATH": f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}"}
        _run(["cmake", str(source), f"-DCMAKE_INSTALL_PREFIX={prefix}",
              f"-DCMAKE_PREFIX_PATH={prefix}", f"-DPython3_EXECUTABLE={sys.executable}",
              "-DCMAKE_BUILD_TYPE=Release", "-DBUILD_TESTING=OFF"], quiet, build_dir, env)
        _run(["cmake", "--build", ".", "--parallel", "2"], quiet, build_dir, env)
        _run(["cmake", "--install", "."], quiet, build_dir, env)


def _use_this_environment(prefix: Path) -> None:
    """Point the wheels' CMake files at this environment's Python and NumPy headers."""
    import numpy

    replacements = {"include": sysconfig.get_paths()["include"], "numpy": numpy.get_include()}
    for path in (prefix / "share").glob("*/cmake/*.cmake"):
        text = path.read_text()
        fixed = _BUILD_MACHINE.sub(
            lambda m: replacements["numpy" if "numpy" in m.group(1) else "include"], text)
        if fixed != text:
            path.write_text(fixed)


def _run(command: list[str], quiet: bool, cwd: Path | None = None,
         env: dict[str, str] | None = None) -> None:
    result = subprocess.run(command, cwd=cwd, env={**os.environ, **(env or {})},
                            capture_output=quiet, text=True, check=False)
    if result.returncode != 0:
        tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-15:]) if quiet \
            else ""
        raise BuildError(f"{' '.join(command[:3])} … failed (exit {result.returncode})\n{tail}")


def main() -> int:
    if available():
        print("tf2_msgs is already importable here: nothing to build")
        return 0
    try:
        build()
    except BuildError as err:
        print(f"houghloc: error: {err}", file=sys.stderr)
        return 1
    # a new interpreter: this one cached the failed look-up
    check = subprocess.run([sys.executable, "-c", "from tf2_msgs.msg import TFMessage"],
                           capture_output=True, text=True, check=False)
    if check.returncode != 0:
        print(f"houghloc: error: tf2_msgs was built but does not import:\n{check.stderr}",
              file=sys.stderr)
        return 1
    print(f"tf2_msgs (TFMessage) built and installed into {sys.prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
