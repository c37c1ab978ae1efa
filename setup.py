"""ament_python build of tank_control (also installable with pip)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'tank_control'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/scenarios', glob('config/scenarios/*.yaml')),
        ('share/' + PACKAGE + '/config/studies', glob('config/studies/*.yaml')),
    ],
    # the dashboard's page and its vendored plotting library (scripts/vendor_uplot.sh)
    package_data={'tank_control.dashboard': ['static/*.*', 'static/vendor/*']},
    install_requires=['setuptools'],
    # tank_control/python_control.py (round trips with python-control), optional
    extras_require={'control': ['control==0.10.2']},
    zip_safe=True,
    maintainer='tank_control team',
    maintainer_email='team@tank-control.invalid',
    description='Process-control runtime for dead-time processes on ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'plant_node = tank_control.nodes.plant_node:main',
            'controller_node = tank_control.nodes.controller_node:main',
            'reference_node = tank_control.nodes.reference_node:main',
            'dashboard_node = tank_control.nodes.dashboard_node:main',
            'opcua_bridge_node = tank_control.nodes.opcua_bridge_node:main',
            'signal_bridge_node = tank_control.nodes.signal_bridge_node:main',
            'ros2 = tank_control.ros2cli.main:main',
            'tank-control = tank_control.harness.cli:main',
        ],
        # the conformance kit's fixtures for users' tests of their kinds (docs/extending.md)
        'pytest11': ['tank_control = tank_control.testing.plugin'],
    },
)
