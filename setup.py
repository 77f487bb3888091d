"""Build script of the ``enbarr`` ament_python package.

Runtime dependencies are pinned in ``requirements.txt`` (installed by ``./dev``), not in
``install_requires``: in a ROS 2 workspace rosdep and the distribution provide them, and
setuptools must not try to fetch them during ``colcon build``.
"""

from glob import glob

from setuptools import find_packages, setup

package_name = 'enbarr'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=['enbarr_core*', 'enbarr_plugins*', 'enbarr_interfaces*']),
    # The surface station's page ships inside its package: no build step, no CDN.
    package_data={'': ['py.typed'], 'enbarr_plugins.station': ['static/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/params', glob('params/*.yaml')),
        ('share/' + package_name + '/params/scenarios', glob('params/scenarios/*.yaml')),
        ('share/' + package_name + '/params/bench', glob('params/bench/*.yaml')),
        # The Arduino board's firmware: the emulator compiles link.c for the host.
        ('share/' + package_name + '/firmware', ['firmware/Makefile']),
        ('share/' + package_name + '/firmware/enbarr_arduino',
         glob('firmware/enbarr_arduino/*.[ch]') + glob('firmware/enbarr_arduino/*.ino')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Enbarr maintainers',
    maintainer_email='maintainers@enbarr.invalid',
    description='Control stack for low-cost marine vehicles, composed from vessel profiles.',
    license='MIT',
    entry_points={
        'console_scripts': [
            'enbarr = enbarr_core.commands.main:main',
            'bringup = enbarr_core.commands.main:bringup_main',
        ],
    },
)
