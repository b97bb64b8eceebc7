"""ament_python package memo_ros; also pip-installable on a machine without ROS."""

from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'memo_ros'

# On a ROS 2 install (colcon, AMENT_PREFIX_PATH set) rclpy and the messages come
# from the distribution; in a plain virtual environment they come from PyPI wheels.
ROS_FROM_PIP = [
    'ros-jazzy-rclpy[fastrtps]==7.1.6',
    'ros-jazzy-common-interfaces==5.3.6',
]
COMMON = [
    'numpy>=1.26,<3',
    'scipy>=1.11',
    'opencv-python-headless>=4.8',
    'PyYAML>=6.0',
    'rosbags>=0.11.9,<0.12',
    'matplotlib>=3.8',
]
install_requires = COMMON + ([] if os.environ.get('AMENT_PREFIX_PATH') else ROS_FROM_PIP)

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'README.md']),
        ('share/' + package_name + '/config', sorted(glob('config/*'))),
        ('share/' + package_name + '/launch', sorted(glob('launch/*.py'))),
    ],
    package_data={package_name: ['config/*']},
    include_package_data=False,
    install_requires=install_requires,
    extras_require={
        'test': [
            'pytest>=8',
            'pytest-xdist>=3.6',  # scripts/test.sh runs the suite on two workers
            'ruff>=0.17',
            'mypy>=2.4',
            'types-PyYAML>=6.0',
            'hypothesis>=6.100',
        ],
        # evaluate --keypoints: BlazePose's weights ship inside this wheel; no node imports it
        'keypoints': ['mediapipe==0.10.14'],
    },
    zip_safe=True,
    maintainer='memo_ros developers',
    maintainer_email='memo_ros@example.org',
    description=(
        'Model-based 3D human posture tracking from calibrated cameras '
        '(MEMO, active multi-viewpoint EKF).'
    ),
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={
        'console_scripts': [
            'memo-ros = memo_ros.tools.cli:main',
            'contour_node = memo_ros.nodes.contour_node:main',
            'selector_node = memo_ros.nodes.selector_node:main',
            'tracker_node = memo_ros.nodes.tracker_node:main',
            'walker_node = memo_ros.nodes.walker_node:main',
        ],
    },
)
