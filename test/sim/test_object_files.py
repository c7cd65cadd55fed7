"""Object YAML files with a section of the wrong type: a clear error naming file and section.

Audit D9: ``geometry``, ``colour`` or ``geometry.undulation`` given as a list raised a bare
``AttributeError`` (``'list' object has no attribute 'get'``), and ``pointforce cell generate
--object bad.yaml`` printed a traceback.
"""

import os

import pytest

from pointforce_ros.bringup.cli import main
from pointforce_ros.dds import PROFILE_VARIABLES
from pointforce_ros.errors import InvalidInput
from pointforce_ros.sim.objects import load_object, OBJECTS_DIR

with open(os.path.join(OBJECTS_DIR, 'dome.yaml'), encoding='utf-8') as _fh:
    DOME = _fh.read()

WRONG_SECTIONS = {
    'geometry': DOME.replace('geometry:\n', 'geometry: [1, 2]\nunused_geometry:\n', 1),
    'material': DOME.replace('material:\n', 'material: soft\nunused_material:\n', 1),
    'colour': DOME.replace('colour:\n', 'colour: [1]\nunused_colour:\n', 1),
    'geometry.undulation': DOME.replace('geometry:\n', 'geometry:\n  undulation: [1, 2]\n', 1),
    'mesh': DOME + '\nmesh: 3\n',
}


def test_a_range_error_names_the_file(tmp_path):
    path = tmp_path / 'soft.yaml'
    path.write_text(DOME.replace('poisson: 0.48', 'poisson: 0.7'))
    assert path.read_text() != DOME
    with pytest.raises(InvalidInput, match=rf'{path} \(dome\): .*poisson 0.7'):
        load_object(str(path))


def test_cell_generate_with_a_bad_object_file_is_an_error_not_a_traceback(
        tmp_path, capsys, monkeypatch):
    for name in PROFILE_VARIABLES:      # main() names a DDS profile: restored after the test
        monkeypatch.delenv(name, raising=False)
    path = tmp_path / 'bad.yaml'
    path.write_text(WRONG_SECTIONS['colour'])
    code = main(['cell', 'generate', '--object', str(path), '--scenario', 'clean',
                 '--pokes', '1', '--out', str(tmp_path / 'out')])
    err = capsys.readouterr().err
    assert code == 2 and str(path) in err and "'colour'" in err and 'Traceback' not in err


OUT_OF_BOUNDS = {           # key in the message -> the dome with that key made hostile
    'live.grid': DOME.replace('grid: [4, 3]', 'grid: [100000, 100000]'),
    'mesh.live': DOME.replace('live: 0.003', 'live: 1.0e-9'),
    'mesh.validation': DOME.replace('validation: 0.0015', 'validation: .nan'),
    'geometry.size': DOME.replace('size: [0.090, 0.080, 0.042]', 'size: [.nan, 0.080, 0.042]'),
    'geometry.centre': DOME.replace('centre: [0.5, 0.0]\n', 'centre: [.inf, 0.0]\n', 1),
    'poke.max_depth': DOME.replace('max_depth: 0.010', 'max_depth: -0.01'),
}


HOSTILE = ([(WRONG_SECTIONS[name], rf"section '{name}' must be a mapping")
            for name in sorted(WRONG_SECTIONS)]
           + [(OUT_OF_BOUNDS[key], rf'\(dome\): {key}') for key in sorted(OUT_OF_BOUNDS)])


@pytest.mark.parametrize('text, match', HOSTILE)
def test_a_bad_section_or_value_names_file_and_key(tmp_path, text, match):
    """A section that is no mapping raised AttributeError; a hostile size or count loaded.

    Audit (session 38): live.grid [100000, 100000] and mesh.live 1e-9 loaded, and the live
    cache would have built 10^10 FEM pokes or a mesh of 10^20 elements; a NaN size loaded too.
    """
    assert text != DOME
    path = tmp_path / 'hostile.yaml'
    path.write_text(text)
    with pytest.raises(InvalidInput, match=rf'{path}.*{match}'):
        load_object(str(path))


def test_cell_generate_refuses_a_huge_live_grid_in_one_line(tmp_path, capsys, monkeypatch):
    for name in PROFILE_VARIABLES:      # main() names a DDS profile: restored after the test
        monkeypatch.delenv(name, raising=False)
    path = tmp_path / 'huge.yaml'
    path.write_text(OUT_OF_BOUNDS['live.grid'])
    code = main(['cell', 'generate', '--object', str(path), '--scenario', 'clean',
                 '--pokes', '0', '--probes', 'point', '--out', str(tmp_path / 'out')])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1
    assert f'{path} (dome): live.grid needs 2 counts in 2..15, got [100000, 100000]' in err
    assert not (tmp_path / 'out').exists()
