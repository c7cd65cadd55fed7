"""Package set-up for pointforce_ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'pointforce_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=['pointforce_ros', 'pointforce_ros.*',
                                    'msg_adapters', 'msg_adapters.*'],
                           exclude=['pointforce_interfaces*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + package_name + '/config/objects', glob('config/objects/*.yaml')),
        ('share/' + package_name + '/config/scenarios', glob('config/scenarios/*.yaml')),
        ('share/' + package_name + '/data/fem', glob('data/fem/*.npz')),
        ('share/' + package_name + '/data/figures', glob('data/figures/*.npz')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='pointforce_ros developers',
    maintainer_email='pointforce@example.com',
    description='Learned point-wise force response of soft objects, served over ROS 2.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pointforce = pointforce_ros.bringup.cli:main',
            'cloud_capture = pointforce_ros.nodes.cloud_capture:main',
            'poke_server = pointforce_ros.nodes.poke_server:main',
            'stiffness_learner = pointforce_ros.nodes.stiffness_learner:main',
            'contact_wrench = pointforce_ros.nodes.contact_wrench:main',
            'deformation_force = pointforce_ros.nodes.deformation_force:main',
            'rtde_emulator = pointforce_ros.sim.rtde.emulator:main',
        ],
    },
)
