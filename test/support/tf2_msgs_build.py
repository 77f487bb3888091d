"""``tf2_msgs`` for the tests where no ROS install provides it: built from PyPI wheels.

PyPI carries no tf2_msgs wheel, so on a pip install the frame publisher's live path (``/tf``
and ``/tf_static`` on DDS) has no message class. The rosidl generators and ament_cmake are on
PyPI (``ros-jazzy-*``, pinned in requirements-test.txt), so this module builds the package the
way a ROS 2 workspace does, with ``rosidl_generate_interfaces`` (the generated C, the C and C++
type supports for Fast DDS and introspection, and the Python module), Debian's cmake and
compilers, and nothing downloaded. Only ``TFMessage`` is built: it is all that ``/tf`` and
``/tf_static`` carry, and a message's wire format and type hash depend on its own definition
and those of the types it holds, not on the other interfaces of its package.

The result is cached under the virtual environment, keyed on every input (the package's
files, the installed ``ros-*`` wheels, cmake, the compilers and Python), so a test run pays the
build at most once; concurrent runs wait on a lock. ``tf2_msgs_environment().environ(env)``
is the environment in which another process imports ``tf2_msgs`` (``PYTHONPATH``,
``LD_LIBRARY_PATH`` for the type support libraries, ``AMENT_PREFIX_PATH``); where ``tf2_msgs``
already imports (a full ROS 2 install), nothing is built. This process itself cannot import
the build: the dynamic loader reads ``LD_LIBRARY_PATH`` only when a process starts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import fcntl
import hashlib
import importlib.metadata
import importlib.util
import os
from pathlib import Path
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import time

#: ``tf2_msgs/msg/TFMessage.msg`` as ros2/geometry2 defines it (branch jazzy, tf2_msgs 0.36.4).
TF_MESSAGE_MSG = 'geometry_msgs/TransformStamped[] transforms\n'

PACKAGE_XML = textwrap.dedent("""\
    <?xml version="1.0"?>
    <package format="3">
      <name>tf2_msgs</name>
      <version>0.36.4</version>
      <description>tf2_msgs/msg/TFMessage alone, built for the Enbarr tests</description>
      <maintainer email="maintainers@enbarr.invalid">Enbarr maintainers</maintainer>
      <license>BSD</license>
      <buildtool_depend>ament_cmake</buildtool_depend>
      <buildtool_depend>rosidl_default_generators</buildtool_depend>
      <depend>builtin_interfaces</depend>
      <depend>geometry_msgs</depend>
      <exec_depend>rosidl_default_runtime</exec_depend>
      <member_of_group>rosidl_interface_packages</member_of_group>
      <export><build_type>ament_cmake</build_type></export>
    </package>
    """)

# The message wheels were built in a manylinux image: their exported Python targets
# (``<pkg>::<pkg>__rosidl_generator_py``, rosidl_generator_py 0.22.2) name that image's Python
# and numpy include folders, which do not exist here, and CMake refuses to generate with a
# missing include folder. This machine's Python and numpy headers take their place.
CMAKELISTS = textwrap.dedent("""\
    cmake_minimum_required(VERSION 3.5)
    project(tf2_msgs)
    find_package(ament_cmake REQUIRED)
    find_package(rosidl_default_generators REQUIRED)
    find_package(builtin_interfaces REQUIRED)
    find_package(geometry_msgs REQUIRED)
    rosidl_generate_interfaces(${PROJECT_NAME}
      "msg/TFMessage.msg"
      DEPENDENCIES builtin_interfaces geometry_msgs
    )
    find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
    get_directory_property(_imported IMPORTED_TARGETS)
    foreach(_target IN LISTS _imported)
      if(_target MATCHES "__rosidl_generator_py$")
        set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES
          "${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
      endif()
    endforeach()
    ament_package()
    """)

SOURCES = {'package.xml': PACKAGE_XML, 'CMakeLists.txt': CMAKELISTS,
           'msg/TFMessage.msg': TF_MESSAGE_MSG}

#: The Debian packages that provide what the build runs (as ./dev installs them).
DEBIAN_PACKAGES = ('cmake', 'g++', 'make')

#: Marks a finished install: a folder without it is an interrupted build, redone.
DONE = '.enbarr-built'


class BuildError(RuntimeError):
    """The build ran and failed: the message holds the failing step and its output's end."""


@dataclass(frozen=True)
class Built:
    """A tf2_msgs install and what it cost."""

    prefix: Path | None     # None: tf2_msgs imports without a build (a full ROS 2 install)
    seconds: float          # the build's wall time; 0.0 when cached or not built

    def environ(self, base: Mapping[str, str]) -> dict[str, str]:
        """``base`` as a child process needs it to import tf2_msgs."""
        return dict(base) if self.prefix is None else environment(self.prefix, base)


def ros_installed() -> bool:
    """Whether ``tf2_msgs`` imports here as it is (a sourced ROS 2 install)."""
    return importlib.util.find_spec('tf2_msgs') is not None


def missing_prerequisites() -> list[str]:
    """What the build needs from the system and lacks, as a person would name it."""
    missing = []
    if shutil.which('cmake') is None:
        missing.append('cmake')
    if shutil.which('cc') is None or shutil.which('c++') is None:
        missing.append('a C and C++ compiler (cc, c++: g++)')
    if shutil.which('ninja') is None and shutil.which('make') is None:
        missing.append('make (or ninja)')
    if not Path(sysconfig.get_paths()['include'], 'Python.h').is_file():
        missing.append(f'the Python {sys.version_info.major}.{sys.version_info.minor} '
                       'headers (Python.h; python3-dev)')
    return missing


def _first_line(*command: str) -> str:
    try:
        out = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError:
        return ''   # not installed: missing_prerequisites() names it
    return next(iter((out.stdout or out.stderr).splitlines()), '')


def cache_key() -> str:
    """A digest of everything the build's result depends on."""
    h = hashlib.sha256()
    for name, text in sorted(SOURCES.items()):
        h.update(f'{name}\0{text}\0'.encode())
    wheels = sorted(f'{d.metadata["Name"]}=={d.version}'
                    for d in importlib.metadata.distributions()
                    if (d.metadata['Name'] or '').lower().startswith('ros-'))
    h.update('\n'.join(wheels).encode())
    h.update(f'{sys.version}\0{sys.prefix}\0'.encode())
    for tool in ('cmake', 'cc', 'c++'):
        h.update(_first_line(tool, '--version').encode())
    return h.hexdigest()[:16]


def cache_root() -> Path:
    """Where builds are kept: in the virtual environment, else the user's cache."""
    if os.access(sys.prefix, os.W_OK):
        return Path(sys.prefix, 'build', 'tf2_msgs')
    return Path.home() / '.cache' / 'enbarr' / 'tf2_msgs'


def site_packages(prefix: Path) -> Path:
    """The folder of an install's Python packages (``lib/pythonX.Y/site-packages``)."""
    return prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' \
        / 'site-packages'


def environment(prefix: Path, base: Mapping[str, str]) -> dict[str, str]:
    """``base`` with the install at ``prefix`` in front of the paths a ROS process searches."""
    env = dict(base)

    def prepend(var: str, path: Path) -> None:
        env[var] = os.pathsep.join([str(path), *filter(None, [base.get(var, '')])])

    prepend('PYTHONPATH', site_packages(prefix))
    prepend('LD_LIBRARY_PATH', prefix / 'lib')
    prepend('AMENT_PREFIX_PATH', prefix)
    return env


def _run(step: str, command: list[str], env: Mapping[str, str], log: Path) -> None:
    with log.open('a') as out:
        out.write(f'$ {" ".join(command)}\n')
        out.flush()
        result = subprocess.run(command, env=env, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, check=False)
    if result.returncode != 0:
        tail = log.read_text(errors='replace')[-4000:]
        raise BuildError(f'building tf2_msgs: {step} failed (exit {result.returncode}; the '
                         'generator wheels are in requirements-test.txt); the end of '
                         f'{log}:\n{tail}')


def build(prefix: Path, key: str) -> None:
    """Generate, compile and install tf2_msgs into ``prefix`` (its build folder is removed)."""
    work = prefix.with_name(prefix.name + '-work')
    shutil.rmtree(work, ignore_errors=True)
    shutil.rmtree(prefix, ignore_errors=True)
    source = work / 'src' / 'tf2_msgs'
    for name, text in SOURCES.items():
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text(text)
    env = dict(os.environ)
    # The wheels' ament index (the type supports to generate) and CMake configs live in the
    # environment's prefix, as in a ROS install's /opt/ros/jazzy.
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(
        filter(None, [sys.prefix, os.environ.get('AMENT_PREFIX_PATH', '')]))
    generator = ['-G', 'Ninja'] if shutil.which('ninja') else []
    log = work / 'build.log'
    _run('configure', ['cmake', '-S', str(source), '-B', str(work / 'build'), *generator,
                       f'-DCMAKE_PREFIX_PATH={sys.prefix}',
                       f'-DPython3_EXECUTABLE={sys.executable}',
                       f'-DCMAKE_INSTALL_PREFIX={prefix}', '-DBUILD_TESTING=OFF',
                       '-DCMAKE_BUILD_TYPE=Release'], env, log)
    _run('compile', ['cmake', '--build', str(work / 'build'), '--parallel',
                     str(os.cpu_count() or 1)], env, log)
    _run('install', ['cmake', '--install', str(work / 'build')], env, log)
    (prefix / DONE).write_text(key + '\n')
    shutil.rmtree(work, ignore_errors=True)


def tf2_msgs_environment() -> Built:
    """tf2_msgs where a child process can import it, built first if needed (and not cached).

    Raises ``BuildError`` when a build ran and failed. The caller checks
    ``missing_prerequisites()`` first (a build without cmake fails at once).
    """
    if ros_installed():
        return Built(None, 0.0)
    root = cache_root()
    root.mkdir(parents=True, exist_ok=True)
    key = cache_key()
    prefix = root / key
    with (root / 'lock').open('w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)   # another run building the same key: wait for it
        seconds = 0.0
        if not (prefix / DONE).is_file():
            for old in root.iterdir():     # builds from other inputs (older wheels): unused
                if old.is_dir():
                    shutil.rmtree(old, ignore_errors=True)
            start = time.monotonic()
            build(prefix, key)
            seconds = time.monotonic() - start
    return Built(prefix, seconds)
