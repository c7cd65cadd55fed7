"""A real pointforce cell: the five nodes on a UR arm and a depth camera, one namespace.

    ros2 launch pointforce_ros cell.launch.py robot_ip:=192.168.1.10 \
        params_file:=$HOME/cell/nodes.yaml namespace:=cell1 \
        cloud_topic:=/camera/camera/depth/color/points

The camera driver (realsense-ros) and the hand-eye calibration publisher are launched by the
cell's own bringup; ``cloud_topic`` points cloud_capture at the camera and ``camera_pose`` in the
parameter file (or a ``cloud_capture/camera_pose`` publisher) places it in ``base``. Every node
reads ``params_file`` (``config/nodes.yaml`` by default: every parameter of the five nodes); the
launch arguments ``robot_ip`` and ``cloud_topic`` (for cloud_capture and deformation_force, which
both read the camera), when given, override the file. Cross-node
names are relative, so ``namespace:=cell1`` keeps the cell together next to another one.

``contact_workers:=N`` (default 1) starts N-1 more contact_wrench processes, named
``contact_wrench_1`` ... ``contact_wrench_<N-1>``, with the file's contact_wrench parameters:
one process answers one query at a time, so more busy planners than one core can serve get a
worker each (8 planners on two processes: ``pointforce bench ros``'s ``load_procs_*``).
"""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

EXECUTABLES = ('cloud_capture', 'poke_server', 'stiffness_learner', 'contact_wrench',
               'deformation_force')


def _nodes(context, *args, **kwargs):
    """Return the five nodes, each with the parameter file and the overrides given."""
    params_file = LaunchConfiguration('params_file').perform(context)
    namespace = LaunchConfiguration('namespace').perform(context)
    cloud_topic = LaunchConfiguration('cloud_topic').perform(context)
    overrides = {
        'poke_server': {'robot_ip': LaunchConfiguration('robot_ip').perform(context)},
        'cloud_capture': {'cloud_topic': cloud_topic},
        'deformation_force': {'cloud_topic': cloud_topic},
    }
    nodes = []
    for executable in EXECUTABLES:
        parameters = [params_file]
        given = {k: v for k, v in overrides.get(executable, {}).items() if v}
        if given:
            parameters.append(given)
        nodes.append(Node(package='pointforce_ros', executable=executable, name=executable,
                          namespace=namespace, parameters=parameters, output='screen',
                          emulate_tty=True))
    workers = int(LaunchConfiguration('contact_workers').perform(context))
    for k in range(1, workers):
        nodes.append(Node(package='pointforce_ros', executable='contact_wrench',
                          name=f'contact_wrench_{k}', namespace=namespace,
                          parameters=[_contact_parameters(params_file)], output='screen',
                          emulate_tty=True))
    return nodes


def _contact_parameters(params_file):
    """Return the file's contact_wrench parameters (a worker's name does not match its key)."""
    with open(params_file) as f:
        content = yaml.safe_load(f) or {}
    return dict(content.get('/**/contact_wrench', {}).get('ros__parameters', {}))


def generate_launch_description():
    """Declare the arguments and start the five nodes."""
    default_params = os.path.join(get_package_share_directory('pointforce_ros'), 'config',
                                  'nodes.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='Parameter file of the five nodes (nodes.yaml)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='Namespace of this cell (e.g. cell1)'),
        DeclareLaunchArgument('robot_ip', default_value='',
                              description='UR controller address; empty: the file\'s robot_ip'),
        DeclareLaunchArgument('cloud_topic', default_value='',
                              description='PointCloud2 topic of the depth camera; empty: the '
                              'file\'s cloud_topic'),
        DeclareLaunchArgument('contact_workers', default_value='1',
                              description='contact_wrench processes (more: contact_wrench_<k>, '
                              'for more busy planners than one process serves)'),
        OpaqueFunction(function=_nodes),
    ])
