# Used by catkin_python_setup() in CMakeLists.txt; do not run directly.
from setuptools import find_packages, setup
from catkin_pkg.python_setup import generate_distutils_setup

setup_args = generate_distutils_setup(
    packages=find_packages(
        where='.',
        include=['multirobot_map_merge', 'multirobot_map_merge.*',
                 'explore', 'explore.*',
                 'fleet_sim', 'fleet_sim.*']),
    package_dir={'': '.'},
)

setup(**setup_args)
