"""ament_python + pip packaging for grass_nrsfm_ros.

`colcon build` (which runs ``setup.py install``/``develop``) installs the executable ``node``
into ``lib/grass_nrsfm_ros`` where ``ros2 run`` looks for it (see setup.cfg). A pip install
(PEP 517 wheel) does not: it would put a ``node`` on the user's PATH and shadow Node.js. Both
routes install ``grass-nrsfm``, whose ``node`` subcommand starts the same node.
"""
from glob import glob
import sys

from setuptools import find_packages, setup

PACKAGE = 'grass_nrsfm_ros'

# Direct setup.py install/develop is how colcon (ament_python) builds; pip builds wheels.
COLCON_STYLE = any(cmd in sys.argv for cmd in ('install', 'develop'))

console_scripts = ['grass-nrsfm = grass_nrsfm_ros.cli:main']
if COLCON_STYLE:
    console_scripts.append('node = grass_nrsfm_ros.node:main')
    console_scripts.append('tracker = grass_nrsfm_ros.tracker_node:main')

PLOT = ['matplotlib>=3.5']     # pictures: grass-nrsfm render, bench plots

ROS_JAZZY_WHEELS = [
    'ros-rclpy[fastrtps]==7.1.6',
    'ros-sensor-msgs==5.3.6',
    'ros-std-msgs==5.3.6',
    'ros-diagnostic-msgs==5.3.6',
    'ros-std-srvs==5.3.6',
    'ros-visualization-msgs==5.3.6',
    'ros-geometry-msgs==5.3.6',
    'ros-builtin-interfaces==2.0.3',
    'ros-rosgraph-msgs==2.0.3',
    'ros-rcl-interfaces==2.0.3',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy>=1.24',
        'scipy>=1.10',
        'scikit-learn>=1.3',
        'threadpoolctl>=3',
        'mcap>=1.1',
        'mcap-ros2-support>=0.5',
        'rosbags>=0.10,<0.12',
        'PyYAML>=6',
        'opencv-python-headless>=4.10,<6',
    ],
    extras_require={
        'ros': ROS_JAZZY_WHEELS,
        'plot': PLOT,
        'test': PLOT + ['pytest>=7', 'hypothesis>=6', 'colcon-common-extensions>=0.3',
                        'flake8>=6', 'flake8-quotes>=3.3', 'flake8-import-order>=0.18'],
    },
    tests_require=['pytest'],
    zip_safe=True,
    maintainer='grass_nrsfm_ros maintainers',
    maintainer_email='maintainers@grass-nrsfm.example.org',
    description='Dense Grassmannian NRSfM (Kumar et al. CVPR 2018) as a ROS 2 Jazzy node.',
    license='Apache-2.0',
    entry_points={'console_scripts': console_scripts},
)
