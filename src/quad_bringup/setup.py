from glob import glob

from setuptools import find_packages, setup

package_name = 'quad_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
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
            'recorder = quad_bringup.recorder_node:main',
        ],
    },
)
