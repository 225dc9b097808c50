"""ament_python build of pulsejet_sim (colcon build, ros2 run pulsejet_sim <executable>)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'pulsejet_sim'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/sweeps', glob('config/sweeps/*.yaml')),
        ('share/' + PACKAGE + '/config/optimize', glob('config/optimize/*.yaml')),
        ('share/' + PACKAGE + '/config/params', glob('config/params/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    # `pulsejet sweep|optimize --scheduler tcp://HOST:PORT | --dask-workers N`; pinned in requirements.txt
    extras_require={'dask': ['dask[distributed]']},
    zip_safe=True,
    maintainer='pulsejet maintainers',
    maintainer_email='maintainers@pulsejet.dev',
    description='Soft pulsed-jet underwater robot simulator for ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'sim_node = pulsejet_sim.sim_node:main',
            'controller_node = pulsejet_ctrl.controller_node:main',
            'recorder = pulsejet_sim.recorder:main',
            'replay = pulsejet_sim.replay:main',
            'pulsejet = pulsejet_sim.cli:main',
        ],
    },
)
