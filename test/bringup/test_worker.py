"""CPU-heavy jobs in a process of their own: the same answers as in the caller's process."""

import os

import numpy as np
import pytest

from pointforce_ros.bringup.worker import in_fresh_process, shape_calibration
from pointforce_ros.contact.identify import (calibrate_shape, decay_grid,
                                             identify_shape_constant_from_probe)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Pose

DOWN = np.array([0.0, 0.0, -1.0])
AT = np.array([0.505, 0.004, 0.04])


def _refuse(value):
    raise InvalidInput(f'refused {value}')


def test_a_job_runs_in_another_process_and_its_error_comes_back():
    assert in_fresh_process(os.getpid) != os.getpid()
    with pytest.raises(InvalidInput, match='refused 3'):
        in_fresh_process(_refuse, 3)


def test_the_worker_calibrates_the_served_model_as_the_caller_would(tmp_path):
    path = save_model(patch_contact_model(spacing=0.003), tmp_path)
    server = WrenchServer()
    server.load(path)
    sim = server.simulator()
    truth = sim.with_shape_constant(0.006, 0.016)
    pushes = []
    for mesh, positions in ((icosphere(0.01, 3), [AT + [0, 0, 0.01 - d] for d in (0.002, 0.003)]),
                            (box([0.006, 0.03, 0.006]),
                             [AT + [-0.008, 0, -d] for d in (0.001, 0.002)])):
        poses = [Pose(position=p) for p in positions]
        force = truth.query_batch(mesh, poses, DOWN, AT).wrenches[:, :3]
        pushes.append((mesh, poses, DOWN, 1.1 * force))          # 10 % no (c, L) explains
    sphere = (*pushes[0][:3], -pushes[0][3] @ DOWN)
    fits = in_fresh_process(shape_calibration, str(path), sphere, pushes)
    assert fits['errors'] == {}
    here = calibrate_shape(sim, pushes, decays=decay_grid(sim.surface))
    there = fits['calibration']
    assert there.fit.c == pytest.approx(here.fit.c, rel=1e-9)
    assert there.fit.decay == here.fit.decay
    assert there.relative_std == pytest.approx(here.relative_std, rel=1e-9)
    assert here.relative_std > 0.01
    np.testing.assert_allclose(there.shape_cov, here.shape_cov, rtol=1e-9)
    alone = identify_shape_constant_from_probe(sim, *sphere)
    assert fits['c_only'].c == pytest.approx(alone.c, rel=1e-9)
    # one push is no joint fit; a push the model cannot fit says why instead of raising
    broken = (*pushes[0][:3], np.array([1.0, np.nan]))
    fits = in_fresh_process(shape_calibration, str(path), broken, pushes[:1])
    assert fits['calibration'] is None and fits['c_only'] is None
    assert 'measured_force' in fits['errors']['sphere'] and 'pushes' not in fits['errors']
