"""Write a calibrated replica to a directory and load it back with one call.

Layout of a replica directory (plain files a user can read without this package)::

    <dir>/body.vtk        tetrahedral mesh of the body, metres, base (legacy ASCII VTK)
    <dir>/pusher.urdf     the prismatic pusher, engine units (lengths times ``scale``)
    <dir>/replica.json    format, material (mu, lambda Pa, damping), engine settings, mesh
                          resolution, calibration summaries and the figures the replica
                          reported when it was written

:func:`load_replica` builds the PyBullet DIRECT scene from those files and returns the body
ids and the plain description.
"""

from dataclasses import asdict, dataclass
import json
from pathlib import Path
from typing import Dict, Mapping, Optional

from pointforce_ros.errors import DataError, InvalidInput, read_json
from pointforce_ros.replica.mesh import read_vtk, TetMesh, write_vtk
from pointforce_ros.replica.scene import Material, pusher_urdf, ReplicaScene, SceneConfig

FORMAT = 'pointforce-replica/1'


def write_replica(out, mesh: TetMesh, material: Material, config: SceneConfig,
                  figures: Optional[Mapping] = None,
                  calibrations: Optional[Mapping] = None) -> Path:
    """Write the replica files into ``out`` (created; files in it are replaced).

    Args:
        out: directory.
        mesh: the body mesh it was calibrated on.
        material: calibrated material.
        config: engine settings it was calibrated with.
        figures: JSON-able figures it reported (errors, simulations, wall time).
        calibrations: JSON-able calibrator summaries.

    Returns:
        The directory.

    Raises:
        DataError: the directory cannot be written.

    """
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_vtk(mesh, out / 'body.vtk')
        plate = config.plate_half_width * config.scale if config.pusher == 'plate' else 0.0
        (out / 'pusher.urdf').write_text(pusher_urdf(config.probe_radius * config.scale,
                                                     config.tip_mass, 0.1 * config.scale,
                                                     plate_half_width=plate))
        desc = {'format': FORMAT, 'material': asdict(material),
                'young_Pa': material.young, 'poisson': material.poisson,
                'config': asdict(config), 'mesh': {'resolution_m': mesh.resolution,
                                                   'nodes': len(mesh.nodes),
                                                   'tets': len(mesh.tets)},
                'figures': dict(figures or {}), 'calibrations': dict(calibrations or {})}
        (out / 'replica.json').write_text(json.dumps(desc, indent=1, default=float))
    except OSError as exc:
        raise DataError(f'cannot write the replica to {out}: {exc}') from exc
    return out


@dataclass(frozen=True)
class LoadedReplica:
    """A replica loaded into a PyBullet DIRECT client.

    Attributes:
        client: PyBullet physics client id.
        body_id: soft body id.
        table_id: table id.
        pusher_id: pusher id (placed above the body's highest node, pushing down).
        scene: the :class:`ReplicaScene` (poke it with ``scene.poke``; ``scene.close()``).
        description: the plain contents of ``replica.json``.

    """

    client: int
    body_id: int
    table_id: int
    pusher_id: int
    scene: ReplicaScene
    description: Dict


def read_description(path) -> Dict:
    """Read and check ``replica.json`` of a replica directory.

    Raises:
        DataError: missing, unreadable or of another format.

    """
    path = Path(path)
    if not (path / 'replica.json').is_file():
        raise DataError(f'{path}: not a replica directory (no replica.json)')
    desc = read_json(path / 'replica.json', 'replica description')
    if desc.get('format') != FORMAT:
        raise DataError(f'{path}: replica format {desc.get("format")!r}, expected {FORMAT}')
    return desc


def load_replica(path) -> LoadedReplica:
    """Load a replica directory into a new PyBullet DIRECT client.

    Raises:
        DataError: not a replica directory, or its files are corrupt.

    """
    path = Path(path)
    desc = read_description(path)
    try:
        material = Material(**desc['material'])
        config = SceneConfig(**desc['config'])
    except (TypeError, KeyError, InvalidInput) as exc:
        raise DataError(f'{path}: bad material or engine settings in replica.json: {exc}') \
            from exc
    mesh = read_vtk(path / 'body.vtk', desc['mesh']['resolution_m'])
    scene = ReplicaScene(mesh, material, config, vtk_path=str(path / 'body.vtk'))
    top = mesh.nodes[mesh.nodes[:, 2].argmax()]
    pusher = scene.place_pusher([top[0], top[1], top[2] + 0.005], [0.0, 0.0, -1.0])
    return LoadedReplica(scene.client, scene.body_id, scene.table_id, pusher, scene, desc)
