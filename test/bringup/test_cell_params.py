"""``pointforce cell --params-file``: the parameter file reaches the cell's nodes (issue 21)."""

import re
from pathlib import Path

import pytest
import yaml
from geometry_msgs.msg import Pose
from pointforce_interfaces.srv import ContactWrenchBatch

from pointforce_ros.bringup import cli
from pointforce_ros.bringup.cell import CellSession

ROOT = Path(__file__).resolve().parents[2]
PARAMS = ROOT / 'config' / 'nodes.yaml'


def test_the_cli_hands_the_checked_file_to_the_cell(monkeypatch):
    seen = {}
    real = cli._load

    def fake_load(target):
        if not target.endswith(':run_cell'):
            assert target.endswith(':load_scenario')   # the scenario checked before the cell
            return real(target)
        return lambda **kwargs: seen.update(kwargs) or 0
    monkeypatch.setattr(cli, '_load', fake_load)
    assert cli.main(['cell', '--params-file', str(PARAMS), '--duration', '0']) == 0
    assert seen['params_file'] == str(PARAMS.resolve())
    seen.clear()
    assert cli.main(['cell', '--duration', '0']) == 0
    assert seen['params_file'] is None


@pytest.mark.parametrize('content, match', [
    (None, 'No such file'),
    ('- a\n- list\n', 'not a mapping'),
    ('poke_srever:\n  ros__parameters: {max_force: 5.0}\n', 'poke_srever.*names no node'),
    ('/**/poke_server:\n  max_force: 5.0\n', 'no ros__parameters'),
    ('poke_server: [\n', 'params-file'),
])
def test_a_bad_file_is_refused_before_anything_starts(tmp_path, monkeypatch, capsys,
                                                      content, match):
    monkeypatch.setattr(cli, '_load', lambda target: pytest.fail('the cell started'))
    path = tmp_path / 'params.yaml'
    if content is not None:
        path.write_text(content)
    assert cli.main(['cell', '--params-file', str(path)]) == 2
    err = capsys.readouterr().err
    assert 'pointforce cell: error' in err
    assert re.search(match, err), err


@pytest.mark.e2e
@pytest.mark.ros
def test_the_cell_nodes_take_the_files_values(tmp_path):
    content = yaml.safe_load(PARAMS.read_text())
    content['/**/contact_wrench']['ros__parameters']['max_batch'] = 3
    content['/**/poke_server']['ros__parameters']['max_force'] = 4.0
    content['/**/stiffness_learner']['ros__parameters']['marker_suggestions'] = 2
    path = tmp_path / 'cell.yaml'
    path.write_text(yaml.safe_dump(content))
    with CellSession(tmp_path / 'cell', object_name='halfspace', scenario='clean',
                     params_file=str(path), log=lambda line: None) as cell:
        # the file's values are in use ...
        assert cell.wrench_node.max_batch == 3
        assert cell.poke_node.limits.max_force == 4.0
        assert cell.learner_node.marker_suggestions == 2
        # ... and the cell's own settings win: its paths, not the file's out/cell
        assert cell.learner_node.store_dir == str(cell.paths['store'])
        request = ContactWrenchBatch.Request(poses=[Pose() for _ in range(4)])
        refused = cell.call(cell.batch_client, request, 20, 'batch')
        assert not refused.success and 'max_batch 3' in refused.message
