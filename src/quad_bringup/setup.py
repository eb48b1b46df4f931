import os
from glob import glob

from setuptools import find_packages, setup

package_name = 'quad_bringup'


def config_files():
    """config/ (a link to the repository's config/) -> share/quad_bringup/config, keeping sub-folders."""
    entries = {}
    for path in sorted(glob('config/**/*.*', recursive=True)):
        entries.setdefault(os.path.join('share', package_name, os.path.dirname(path)), []).append(path)
    return list(entries.items())

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={'quad_bringup.peers': ['peer_constraints.txt']},   # peer_venv reads it beside its module
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
        *config_files(),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='quadflight developers',
    maintainer_email='dev@quadflight.invalid',
    description='Launch files, the quadflight command (plan, fly, record, report) and the rosbag2 recorder.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'quadflight = quad_bringup.cli:main',
            'recorder = quad_bringup.recording.start:recorder',
        ],
    },
)
