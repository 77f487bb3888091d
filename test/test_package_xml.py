"""``package.xml`` names what the code imports, no more and no less, as rosdep keys.

A colcon + rosdep install gets exactly what ``package.xml`` lists, so a driver's library that
is missing there is missing on the vehicle. This test walks the imports of the installed
packages (``enbarr_core``, ``enbarr_plugins``, ``enbarr_interfaces``: run-time) and of
``test/`` (tests), maps each third-party top-level module to its key through ``KEYS`` (the one
table; a key is what rosdistro's ``rosdep/base.yaml``/``python.yaml`` or a ROS package name
defines, or a ``-pip`` key that package.xml's comment explains), and compares:

- an import with no row in ``KEYS`` fails (add the row, and the key to package.xml);
- a run-time key missing from ``exec_depend``/``depend``, or a test key missing from those and
  from ``test_depend``, fails;
- a key in package.xml that nothing imports fails, and so does a ``test_depend`` that is a
  run-time key already.
"""

from __future__ import annotations

from collections import defaultdict
from functools import cache
import importlib.util
from pathlib import Path
import sys
import xml.etree.ElementTree as ET

from support.sources import imports, PACKAGES, python_files, ROOT, TESTS

# Top-level module -> rosdep key. ROS packages are their own key.
KEYS = {
    # ROS 2 packages
    'rclpy': 'rclpy',
    'rcl_interfaces': 'rcl_interfaces',
    'builtin_interfaces': 'builtin_interfaces',
    'rosgraph_msgs': 'rosgraph_msgs',
    'rosidl_parser': 'rosidl_parser',
    'std_msgs': 'std_msgs',
    'sensor_msgs': 'sensor_msgs',
    'geometry_msgs': 'geometry_msgs',
    'nav_msgs': 'nav_msgs',
    'diagnostic_msgs': 'diagnostic_msgs',
    'trajectory_msgs': 'trajectory_msgs',
    'visualization_msgs': 'visualization_msgs',
    'ament_index_python': 'ament_index_python',
    'tf2_msgs': 'tf2_msgs',
    # Python libraries (rosdistro rosdep/python.yaml)
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'filterpy': 'python3-filterpy-pip',
    'rosbags': 'python3-rosbags-pip',
    'serial': 'python3-serial',
    'smbus2': 'python3-smbus2',
    'gpiozero': 'python3-gpiozero',
    'lgpio': 'python3-lgpio',
    'evdev': 'python3-evdev',
    'aiohttp': 'python3-aiohttp',
    'selenium': 'python3-selenium',
    'cv2': 'python3-opencv',
    'pytest': 'python3-pytest',
    'websockets': 'python3-websockets',
    'control': 'python-control-pip',
    'mcap_ros2': 'mcap-ros2-support',
    # No rosdistro key (package.xml says so): the -pip convention
    'mcap': 'python3-mcap-pip',
    'qtm_rt': 'python3-qtm-rt-pip',
    'daqp': 'python3-daqp-pip',
    'quadprog': 'python3-quadprog-pip',
    'onnx': 'python3-onnx-pip',
    'foxglove': 'python3-foxglove-sdk-pip',
}

RUN_TAGS = ('depend', 'exec_depend')
TEST_TAGS = ('test_depend',)


def declared(xml: str) -> dict[str, set[str]]:
    """The keys of package.xml by tag."""
    out: dict[str, set[str]] = defaultdict(set)
    for element in ET.fromstring(xml):
        if element.tag.endswith('depend') and element.text:
            out[element.tag].add(element.text.strip())
    return out


@cache
def is_local(module: str) -> bool:
    """Whether the top-level ``module`` is this repository's own, as Python resolves it here:
    the packages, and ``test/``'s helpers (``test/`` is on the path: ``support``,
    ``recording.small_disk``, ``test.conftest``). Resolved, not guessed from folder names:
    ``import control`` in a test is python-control, not the namespace ``test/control``."""
    spec = importlib.util.find_spec(module)
    if spec is None:
        return False
    places = [spec.origin] if spec.origin else list(spec.submodule_search_locations or ())
    return bool(places) and all(ours(Path(p)) for p in places)


def ours(path: Path) -> bool:
    """Whether ``path`` is in this repository and not in an environment kept there (.venv)."""
    path = path.resolve()
    return path.is_relative_to(ROOT) and not path.is_relative_to(Path(sys.prefix).resolve())


def third_party(*tops: str) -> dict[str, list[str]]:
    """Each third-party top-level module imported under ``tops`` -> where (path:line)."""
    found: dict[str, list[str]] = defaultdict(list)
    for path in python_files(*tops):
        for imp in imports(path):
            if imp.module not in sys.stdlib_module_names and not is_local(imp.module):
                found[imp.module].append(f'{imp.path}:{imp.line}')
    return found


def problems(xml: str, run: dict[str, list[str]], test: dict[str, list[str]]) -> list[str]:
    """What is wrong with ``xml`` for these imports (empty: nothing)."""
    out = []
    for module, where in sorted({**test, **run}.items()):
        if module not in KEYS:
            out.append(f'{module} (imported at {where[0]}) has no rosdep key in KEYS')
    tags = declared(xml)
    run_keys = {k for t in RUN_TAGS for k in tags[t]}
    test_keys = {k for t in TEST_TAGS for k in tags[t]}
    needed_run = {KEYS[m]: w for m, w in run.items() if m in KEYS}
    needed_test = {KEYS[m]: w for m, w in test.items() if m in KEYS}
    for key, where in sorted(needed_run.items()):
        if key not in run_keys:
            out.append(f'exec_depend {key} is missing (imported at {where[0]})')
    for key, where in sorted(needed_test.items()):
        if key not in run_keys | test_keys:
            out.append(f'test_depend {key} is missing (imported at {where[0]})')
    for key in sorted(run_keys - set(needed_run)):
        use = ' (only tests import it: a test_depend)' if key in needed_test else ''
        out.append(f'exec_depend {key}: nothing in the package imports it{use}')
    for key in sorted(test_keys - set(needed_test)):
        out.append(f'test_depend {key}: no test imports it')
    for key in sorted(test_keys & run_keys):
        out.append(f'test_depend {key}: already a run-time dependency')
    return out


def test_package_xml_lists_every_import_and_nothing_else() -> None:
    xml = (ROOT / 'package.xml').read_text(encoding='utf-8')
    found = problems(xml, third_party(*PACKAGES), third_party(TESTS))
    assert not found, 'package.xml:\n  ' + '\n  '.join(found)


def test_the_drivers_libraries_are_found() -> None:
    """The walk sees the lazy imports inside the drivers (a check that it walks at all)."""
    run = third_party(*PACKAGES)
    assert {'cv2', 'evdev', 'gpiozero', 'lgpio', 'qtm_rt', 'serial', 'smbus2'} <= set(run)
    assert 'control' not in run and 'control' in third_party(TESTS)


def test_each_kind_of_difference_is_named() -> None:
    """What the comparison reports, on a made-up package.xml and made-up imports."""
    xml = ('<package format="3"><exec_depend>python3-numpy</exec_depend>'
           '<exec_depend>python3-scipy</exec_depend><test_depend>python3-numpy</test_depend>'
           '<test_depend>python-control-pip</test_depend></package>')
    run = {'numpy': ['a.py:1'], 'cv2': ['b.py:2'], 'pyfoo': ['c.py:3']}
    test = {'numpy': ['t.py:1'], 'pytest': ['t.py:2']}
    assert problems(xml, run, test) == [
        'pyfoo (imported at c.py:3) has no rosdep key in KEYS',
        'exec_depend python3-opencv is missing (imported at b.py:2)',
        'test_depend python3-pytest is missing (imported at t.py:2)',
        'exec_depend python3-scipy: nothing in the package imports it',
        'test_depend python-control-pip: no test imports it',
        'test_depend python3-numpy: already a run-time dependency',
    ]
