from setuptools import find_packages, setup

package_name = 'quad_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['*.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='quadflight developers',
    maintainer_email='dev@quadflight.invalid',
    description='Shared core for quadflight: rotations, state/setpoint types, the sampled-trajectory interpolant, message conversions, parameter and diagnostics helpers.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
    },
)
