from setuptools import find_packages, setup

package_name = 'quad_control'

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
    description='Position controllers (the seed cascaded PD, PID, SE(3)), the attitude law of the seed eq. 6, and the fixed-rate position_controller node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'position_controller = quad_control.start:position_controller',
        ],
    },
)
