"""The identified deformation model on disk, and the camera-vs-F/T consistency check.

A model file ``deformation-v<version>.npz`` holds the volume mesh, the identified material, the
rest-scan offsets and the fit's figures; it is written atomically (a temporary file in the same
folder, then ``os.replace``), so a reader sees the old file or the new one, never half of one,
and versions only grow (:func:`save_model` picks the next). Units SI, frame ``base``. A model
identified for the fused force also holds its :class:`.fusion.FusionData` (``fusion_*``
arrays, same layout version); files written before it load with ``fusion`` None.

:func:`ft_consistency` compares a camera-only force estimate with the F/T reading at the same
instant: a broken, drifting or saturated F/T sensor shows up as a difference beyond their
combined uncertainty.
"""

from dataclasses import dataclass
import os
import re
from typing import Optional

import numpy as np

from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.deformation.force import ForceEstimate
from pointforce_ros.deformation.fusion import FusionData
from pointforce_ros.deformation.mesh import TetMesh
from pointforce_ros.errors import DataError, InvalidInput, reading
from pointforce_ros.types import as_array

FORMAT = 1
"""Version of the file layout (not the model version)."""

_NAME = re.compile(r'^deformation-v(\d+)\.npz$')


@dataclass(frozen=True)
class DeformationModel:
    """An identified deformation model.

    Attributes:
        mesh: the volume mesh.
        young: Young's modulus, Pa: scalar, or (M,) per element.
        poisson: Poisson ratio.
        rest_offset: (N,) rest-scan offsets of the surface nodes, metres.
        load_radius: load patch radius the model was identified with, metres.
        residual_rms: identification residual, metres.
        version: model version (0 until saved).
        fusion: what the fused force needs from the identification pushes
            (:func:`.fusion.fusion_data`), or None (a model identified before it).

    """

    mesh: TetMesh
    young: object
    poisson: float
    rest_offset: np.ndarray
    load_radius: float
    residual_rms: float = float('nan')
    version: int = 0
    fusion: Optional[FusionData] = None

    def build(self) -> CorotationalFem:
        """Return the factorised FEM of this model."""
        return CorotationalFem(self.mesh, self.young, self.poisson)


def model_versions(folder: str) -> list:
    """Sorted versions of the model files in ``folder`` (empty when none or no folder)."""
    if not os.path.isdir(folder):
        return []
    return sorted(int(m.group(1)) for m in map(_NAME.match, os.listdir(folder)) if m)


def save_model(folder: str, model: DeformationModel) -> str:
    """Write ``model`` atomically as the next version in ``folder``; return the path.

    Raises:
        DataError: the folder cannot be created or written.

    """
    try:
        os.makedirs(folder, exist_ok=True)
        version = (model_versions(folder) or [0])[-1] + 1
        path = os.path.join(folder, f'deformation-v{version}.npz')
        tmp = os.path.join(folder, f'.deformation-v{version}.tmp.npz')
        m = model.mesh
        fusion = {}
        if model.fusion is not None:
            f = model.fusion
            fusion = dict(fusion_spread=f.fem_spread, fusion_source=np.str_(f.spread_source),
                          fusion_tips=f.tips, fusion_forces=f.forces, fusion_sites=f.sites,
                          fusion_errors=f.errors, fusion_seconds=f.seconds)
        np.savez_compressed(
            tmp, format=FORMAT, version=version, nodes=m.nodes, tets=m.tets,
            fixed_nodes=m.fixed_nodes, surface_triangles=m.surface_triangles,
            element_size=m.element_size, young=np.asarray(model.young, dtype=float),
            poisson=model.poisson, rest_offset=model.rest_offset,
            load_radius=model.load_radius, residual_rms=model.residual_rms, **fusion)
        os.replace(tmp, path)
    except OSError as exc:
        raise DataError(f'cannot save the deformation model in {folder}: {exc}')
    return path


def load_model(path: str) -> DeformationModel:
    """Read a model file.

    Raises:
        DataError: missing, unreadable, or of another file format.

    """
    with reading(path, 'deformation model'):
        with np.load(path, allow_pickle=False) as data:
            d = dict(data)
        if int(d.get('format', -1)) != FORMAT:
            raise DataError(f'{path}: deformation model format {d.get("format")} is not '
                            f'{FORMAT}')
        return _model_from_arrays(d)


def _model_from_arrays(d: dict) -> DeformationModel:
    """Build the model from the arrays of its file (a missing one raises KeyError)."""
    mesh = TetMesh(nodes=d['nodes'], tets=d['tets'], fixed_nodes=d['fixed_nodes'],
                   surface_triangles=d['surface_triangles'],
                   element_size=float(d['element_size']))
    young = d['young']
    fusion = None
    if 'fusion_spread' in d:   # older files have none: the fused force then uses defaults
        fusion = FusionData(fem_spread=float(d['fusion_spread']),
                            spread_source=str(d['fusion_source']), tips=d['fusion_tips'],
                            forces=d['fusion_forces'], sites=d['fusion_sites'],
                            errors=d['fusion_errors'], seconds=float(d['fusion_seconds']))
    return DeformationModel(mesh=mesh, young=float(young) if young.ndim == 0 else young,
                            poisson=float(d['poisson']), rest_offset=d['rest_offset'],
                            load_radius=float(d['load_radius']),
                            residual_rms=float(d['residual_rms']), version=int(d['version']),
                            fusion=fusion)


def load_latest(folder: str) -> Optional[DeformationModel]:
    """Return the newest model in ``folder``, or None when there is none."""
    versions = model_versions(folder)
    if not versions:
        return None
    return load_model(os.path.join(folder, f'deformation-v{versions[-1]}.npz'))


@dataclass(frozen=True)
class FtConsistency:
    """Camera-only force against the F/T reading.

    Attributes:
        camera_force: (3,) camera estimate, newtons, ``base``.
        ft_force: (3,) F/T reading (force on the object), newtons, ``base``.
        distance: Mahalanobis distance of the difference under the combined covariance.
        consistent: ``distance <= threshold``.
        message: one line for a log or a diagnostic report.

    """

    camera_force: np.ndarray
    ft_force: np.ndarray
    distance: float
    consistent: bool
    message: str


def ft_consistency(estimate: ForceEstimate, ft_force, ft_sigma: float = 0.1,
                   model_rel_sigma: float = 0.1, threshold: float = 3.0) -> FtConsistency:
    """Whether a camera-only estimate and an F/T reading agree within their uncertainty.

    The combined covariance is the estimate's fit covariance, plus the model's own error
    (``model_rel_sigma`` of ``|F|`` per axis: the identified model is not the object; the cell
    evaluation measured 5-15 %), plus the F/T noise ``ft_sigma`` per axis.

    Args:
        estimate: the camera-only estimate.
        ft_force: (3,) F/T force on the object, newtons, ``base``.
        ft_sigma: F/T standard deviation per axis, newtons.
        model_rel_sigma: relative model error per axis.
        threshold: largest Mahalanobis distance called consistent.

    Raises:
        InvalidInput: non-finite reading or non-positive sigmas or threshold.

    """
    ft = as_array(ft_force, 'ft_force', (3,))
    if not ft_sigma > 0 or not model_rel_sigma >= 0 or not threshold > 0:
        raise InvalidInput('ft_consistency: need ft_sigma > 0, model_rel_sigma >= 0, '
                           'threshold > 0')
    mag = max(np.linalg.norm(estimate.force), np.linalg.norm(ft))
    cov = (np.asarray(estimate.covariance) + ((model_rel_sigma * mag) ** 2 + ft_sigma ** 2)
           * np.eye(3))
    diff = estimate.force - ft
    dist = float(np.sqrt(diff @ np.linalg.solve(cov, diff)))
    ok = dist <= threshold
    msg = (f'camera {np.round(estimate.force, 2).tolist()} N vs F/T {np.round(ft, 2).tolist()} N:'
           f' {dist:.1f} sigma ' + ('(consistent)' if ok else
                                    f'> {threshold:g}: F/T or model disagrees (saturated, '
                                    f'drifting or broken F/T, or a contact elsewhere)'))
    return FtConsistency(camera_force=estimate.force, ft_force=ft, distance=dist,
                         consistent=ok, message=msg)
