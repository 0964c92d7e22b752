"""``tf2_msgs/msg/TFMessage`` (and ``nav2_msgs/srv/SetInitialPose``) in a virtual environment
whose ROS 2 comes from PyPI.

The node publishes ``map → odom`` on ``/tf`` as AMCL does, which takes ``tf2_msgs``, and offers
AMCL's ``set_initial_pose`` service, which takes ``nav2_msgs``. A robot's ROS 2 and nav2 install
has both; the PyPI wheels of ROS 2 Kilted (the ``ros2`` extra) do not. This module builds them
the way ROS builds any message package (``rosidl_generate_interfaces`` with the wheels' own
generators, CMake and the C compiler) and installs them into the running environment::

    python -m fusion.ros2.tf2_msgs

The interfaces are ROS 2's and nav2's own definitions, so their type hashes, and every peer's,
agree. Only what the node uses is built: ``TFMessage`` (not tf2's services and actions), and
``SetInitialPose`` (not nav2's other interfaces); a ``nav2_msgs`` already importable (a nav2
install) is left alone.

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
from dataclasses import dataclass
from pathlib import Path

TF_MESSAGE = "geometry_msgs/TransformStamped[] transforms\n"
"""tf2_msgs/msg/TFMessage.msg, as in ROS 2 (geometry2)."""
SET_INITIAL_POSE = "geometry_msgs/PoseWithCovarianceStamped pose\n---\n"
"""nav2_msgs/srv/SetInitialPose.srv, as in nav2."""


@dataclass(frozen=True)
class Interfaces:
    """One interface package to build: its name, version, licence and files (path → text)."""

    name: str
    version: str
    license: str
    files: dict[str, str]


PACKAGES = (Interfaces("tf2_msgs", "0.43.0", "BSD-3-Clause", {"msg/TFMessage.msg": TF_MESSAGE}),
            Interfaces("nav2_msgs", "1.4.0", "Apache-2.0",
                       {"srv/SetInitialPose.srv": SET_INITIAL_POSE}))

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
  <name>{name}</name>
  <version>{version}</version>
  <description>{interfaces} of {name}, built for houghloc's ROS 2 node</description>
  <maintainer email="houghloc@example.org">houghloc</maintainer>
  <license>{license}</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""

CMAKE_LISTS = """cmake_minimum_required(VERSION 3.20)
project({name})
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(${{PROJECT_NAME}} {interfaces} DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""

_BUILD_MACHINE = re.compile(r"/opt/python/cp\d+-cp\d+t?/(include/python3\.\d+t?|"
                            r"lib/python3\.\d+t?/site-packages/numpy/_core/include)")


class BuildError(RuntimeError):
    """The message could not be built here; the text says what is missing."""


def available(module: str = "tf2_msgs.msg") -> bool:
    """Whether ``module`` (``tf2_msgs.msg``, ``nav2_msgs.srv``) can be imported here."""
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def build(package: Interfaces, prefix: Path | None = None, quiet: bool = True) -> None:
    """Build ``package`` and install it into ``prefix`` (default: this environment)."""
    prefix = Path(prefix or sys.prefix)
    for tool in ("cmake", "cc", "make"):
        if shutil.which(tool) is None:
            raise BuildError(f"building {package.name} needs {tool} (install CMake and a C "
                             "compiler)")
    _run([sys.executable, "-m", "pip", "install", "--quiet", *BUILD_REQUIREMENTS], quiet)
    _use_this_environment(prefix)
    with tempfile.TemporaryDirectory(prefix=f"{package.name}-") as tmp:
        source, build_dir = Path(tmp) / package.name, Path(tmp) / "build"
        for name, text in package.files.items():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            (source / name).write_text(text)
        quoted = " ".join(f'"{name}"' for name in package.files)
        (source / "package.xml").write_text(PACKAGE_XML.format(
            name=package.name, version=package.version, license=package.license,
            interfaces=", ".join(package.files)))
        (source / "CMakeLists.txt").write_text(CMAKE_LISTS.format(name=package.name,
                                                                  interfaces=quoted))
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
    for package in PACKAGES:
        module = f"{package.name}.{next(iter(package.files)).split('/')[0]}"
        if available(module):
            print(f"{package.name} is already importable here: nothing to build")
            continue
        try:
            build(package)
        except BuildError as err:
            print(f"houghloc: error: {err}", file=sys.stderr)
            return 1
        # a new interpreter: this one cached the failed look-up
        check = subprocess.run([sys.executable, "-c", f"import {module}"],
                               capture_output=True, text=True, check=False)
        if check.returncode != 0:
            print(f"houghloc: error: {package.name} was built but does not import:\n"
                  f"{check.stderr}", file=sys.stderr)
            return 1
        print(f"{package.name} ({', '.join(package.files)}) built and installed into "
              f"{sys.prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
