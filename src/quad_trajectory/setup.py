from setuptools import find_packages, setup

package_name = 'quad_trajectory'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='quadflight developers',
    maintainer_email='dev@quadflight.invalid',
    description='Minimum-acceleration/jerk/snap trajectory planning through waypoints, and the trajectory_node that publishes the plan.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'trajectory_node = quad_trajectory.start:trajectory_node',
        ],
    },
)
