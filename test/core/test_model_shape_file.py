"""The shape function set at run time is kept beside the models; a reproduced model keeps its file.

Issue 16 item 8: a shape-constant update was lost on restart and the version went back down.
"""

import dataclasses
import json

import numpy as np
import pytest

from pointforce_ros.contact.simulator import ContactSimulator, DECAY_LAW, DECAY_LAWS
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import (ContactModel, load_model, load_shape, load_shape_law,
                                        load_shape_uncertainty, save_model, save_shape,
                                        SHAPE, version_of_path)
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.shapes import cylinder
from pointforce_ros.types import ContactQuery, Pose

MODEL = patch_contact_model(spacing=0.006)


def test_shape_round_trip_with_and_without_a_decay_length(tmp_path):
    assert load_shape(tmp_path) is None
    save_shape(tmp_path, 0.0007, 0.008)
    assert load_shape(tmp_path) == pytest.approx((0.0007, 0.008))
    save_shape(tmp_path, 0.003)
    c, decay = load_shape(tmp_path)
    assert c == pytest.approx(0.003) and np.isinf(decay)
    assert [p.name for p in tmp_path.iterdir()] == [SHAPE]   # no temporary file left


@pytest.mark.parametrize('c, decay', [(0.0, np.inf), (np.nan, np.inf), (0.004, -1.0)])
def test_invalid_shapes_are_refused_before_writing(tmp_path, c, decay):
    with pytest.raises(InvalidInput):
        save_shape(tmp_path, c, decay)
    assert not (tmp_path / SHAPE).exists()


@pytest.mark.parametrize('text', ['', '{"shape_constant": -1}', '[1, 2]', 'not json',
                                  '{"shape_constant": 0.004, "shape_decay": 0}'])
def test_an_unreadable_shape_file_is_a_data_error(tmp_path, text):
    (tmp_path / SHAPE).write_text(text)
    with pytest.raises(DataError, match='shape'):
        load_shape(tmp_path)


def test_a_model_reproduced_under_a_lower_version_gets_the_newest_identical_file(tmp_path):
    """v4 (c = 4 mm), v5 (c = 0.7 mm); a restarted learner with c = 0.7 mm asks for v4 again."""
    v4 = dataclasses.replace(MODEL, version=4, shape_constant=0.004)
    v5 = dataclasses.replace(MODEL, version=5, shape_constant=0.0007)
    assert version_of_path(save_model(v4, tmp_path)) == 4
    assert version_of_path(save_model(v5, tmp_path)) == 5
    again = dataclasses.replace(v5, version=4)
    assert version_of_path(save_model(again, tmp_path)) == 5       # same content: same file
    other = ContactModel(surface=MODEL.surface, response=MODEL.response, shape_constant=0.002,
                         version=4)
    assert version_of_path(save_model(other, tmp_path)) == 6       # new content: next version
    assert sorted(p.name for p in tmp_path.glob('model-v*.npz')) == [
        'model-v000004.npz', 'model-v000005.npz', 'model-v000006.npz']


def test_uncertainty_sources_round_trip_and_bad_ones_are_refused(tmp_path):
    assert load_shape_uncertainty(tmp_path) == {}
    save_shape(tmp_path, 0.003, 0.01, {'shape_cov': [0.04, 0.5, 0.5, 400.0],
                                       'relative_std': 0.05, 'lateral_std': 0.0})
    assert load_shape_uncertainty(tmp_path) == {'shape_cov': [[0.04, 0.5], [0.5, 400.0]],
                                                'relative_std': 0.05}
    assert load_shape(tmp_path) == pytest.approx((0.003, 0.01))
    for bad, match in [({'shape_cov': [0.04, 0.5, -0.5, 400.0]}, 'symmetric'),
                       ({'shape_cov': [-0.04, 0.0, 0.0, 1.0]}, 'non-negative'),
                       ({'shape_cov': [1.0, 2.0, 3.0]}, '4 entries'),
                       ({'relative_std': float('nan')}, 'relative_std')]:
        with pytest.raises(InvalidInput, match=match):
            save_shape(tmp_path, 0.003, 0.01, bad)
    (tmp_path / SHAPE).write_text('{"shape_constant": 0.003, "uncertainty": {"bias": 1}}')
    with pytest.raises(DataError, match='unknown uncertainty sources'):
        load_shape_uncertainty(tmp_path)


def test_a_calibration_keeps_the_decay_law_it_was_identified_under(tmp_path):
    """(c, L) identified under one law, served under the other, answer another force.

    A model or shape file written before the law was stored (no ``shape_decay_law``) was
    identified under ``'fixed'`` and is read so; a new one round-trips its law.
    """
    assert load_shape_law(tmp_path) == DECAY_LAW              # nothing stored: the default
    (tmp_path / SHAPE).write_text('{"shape_constant": 0.003, "shape_decay": 0.008}')
    assert load_shape_law(tmp_path) == 'fixed'                # a file from before the law
    save_shape(tmp_path, 0.003, 0.008, decay_law='penetration')
    assert load_shape_law(tmp_path) == 'penetration'
    (tmp_path / SHAPE).write_text('{"shape_constant": 0.003, "shape_decay_law": "bent"}')
    with pytest.raises(DataError, match='bent'):
        load_shape_law(tmp_path)
    with pytest.raises(InvalidInput, match='decay_law'):
        save_shape(tmp_path, 0.003, 0.008, decay_law='bent')

    base = dataclasses.replace(MODEL, shape_decay=0.006)
    answers = {}
    for law in DECAY_LAWS:
        folder = tmp_path / law
        path = save_model(dataclasses.replace(base, shape_decay_law=law), folder)
        loaded = load_model(path)                              # its SHA-256 checked
        assert loaded.shape_decay_law == law
        server = WrenchServer(spacing=0.003)
        server.swap(loaded)
        # a wide contact: a 10 mm cylinder 30 mm long lying on the patch, 3 mm deep
        query = ContactQuery(mesh=cylinder(0.01, 0.03),
                             poses=(Pose(position=[0.5, 0.0, 0.04 - 0.003]),),
                             approach=[0, 0, -1], torque_centre=[0.5, 0.0, 0.04])
        answers[law] = server.answer(query)[0].wrench.force[2]
        simulator = ContactSimulator(loaded.surface, loaded.response, loaded.shape_constant,
                                     spacing=0.003, decay=0.006, decay_law=law)
        expected = simulator.query(query.mesh, query.poses[0], query.approach,
                                   query.torque_centre).wrench.force[2]
        assert answers[law] == pytest.approx(expected, rel=1e-12)
    # a file without the key (as before the law was stored) is the fixed law's
    with np.load(save_model(dataclasses.replace(base, shape_decay_law='fixed'),
                            tmp_path / 'old')) as z:
        assert 'shape_decay_law' not in json.loads(bytes(z['header']).decode())
    # the two laws differ on a wide contact by more than rounding: the law matters
    assert abs(answers['penetration'] - answers['fixed']) > 0.01 * abs(answers['fixed'])
    with pytest.raises(InvalidInput, match='shape_decay_law'):
        dataclasses.replace(base, shape_decay_law='bent')
