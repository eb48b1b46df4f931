from setuptools import find_packages, setup

package_name = 'quad_vehicle_emu'

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
    description='A PX4 or ArduPilot Copter vehicle behind a real MAVLink endpoint (quad_sim physics), written from '
                "the autopilots' own documentation and source, independent of quad_bridge.",
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'mavlink_vehicle = quad_vehicle_emu.mavlink_vehicle:main',
        ],
    },
)
