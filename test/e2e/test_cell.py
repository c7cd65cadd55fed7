"""The whole node suite on the simulated cell (analytic object): capture, poke, learn, query."""

import numpy as np
import pytest
from geometry_msgs.msg import Vector3

from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.bringup.cell import CellSession
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import PokeGoal, Pose

pytestmark = [pytest.mark.e2e, pytest.mark.ros]


def test_capture_poke_learn_and_query_on_the_simulated_cell(tmp_path):
    from pointforce_interfaces.srv import ContactWrench
    with CellSession(tmp_path, object_name='halfspace', scenario='clean',
                     log=lambda line: None) as cell:
        surface = cell.capture_surface(views=2)
        top = surface.points[:, 2] > 0.035
        assert top.sum() > 100 and np.median(surface.normals[top, 2]) > 0.95
        idx = int(np.argmin(np.linalg.norm(surface.points - [0.5, 0.0, 0.04], axis=1)))
        for k, index in enumerate([idx, idx + 7]):
            goal = PokeGoal(point=surface.points[index], normal=surface.normals[index],
                            surface_index=index, force_limit=3.0, depth_limit=0.01,
                            speed=0.005, standoff=0.006)
            result = cell.poke(poke_goal_to_msg(goal))
            assert result.outcome == 'force_limit', result.message
            cell.wait_model(k + 1)
        suggestion = cell.suggest(2)
        assert suggestion.success and len(suggestion.surface_indices) == 2
        pose = Pose(position=[0.5, 0.0, 0.04 + 0.02 - 0.003])
        answer = cell.call(cell.wrench_client, ContactWrench.Request(
            mesh=mesh_to_msg(icosphere(0.02, 2)), pose=pose_to_msg(pose),
            approach=Vector3(x=0.0, y=0.0, z=-1.0), torque_centre=to_point(pose.position)))
        assert answer.success and answer.model_version == 2
        assert answer.wrench.force.z > 0.5 and answer.contact_count > 0
