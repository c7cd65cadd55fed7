"""The identified deformation model on disk, and the camera-vs-F/T consistency check.

A model file ``deformation-v<version>.npz`` holds the volume mesh, the identified material, the
rest-scan offsets and the fit's figures; it is written atomically (a temporary file in the same
folder, then ``os.replace``), so a reader sees the old file or the new one, never half of one,
and versions only grow (:func:`save_model` picks the next). Units SI, frame ``base``. A model
identified for the fused force also holds its :class:`.fusion.FusionData` (``fusion_*``
arrays, same layout version); files written before it load with ``fusion`` None.

:func:`load_model` checks the content, not only the layout (at most
:data:`MAX_FILE_BYTES` uncompressed, checked before reading; finite nodes, at most
:data:`.mesh.MAX_MESH_NODES`, integer tetrahedra that index them with positive volume, a
support of 3 or more fixed nodes not on one line, surface triangles, a modulus in
[:data:`MIN_YOUNG`, :data:`MAX_YOUNG`] with a contrast up to :data:`MAX_YOUNG_CONTRAST`, a
Poisson ratio in :data:`POISSON_RANGE`, bounded rest offsets and load radius, a version equal
to the one in the file name, ...): a bad file
is a :class:`DataError` naming it, never a bare error from the FEM later. As for the contact
models (:mod:`pointforce_ros.model.files`), :func:`load_latest` moves a file it cannot load to
``quarantine/`` beside it with a ``.reason.txt`` and falls back to the newest valid version; a
quarantined version is never reused by a later save.

:func:`ft_consistency` compares a camera-only force estimate with the F/T reading at the same
instant: a broken, drifting or saturated F/T sensor shows up as a difference beyond their
combined uncertainty.
"""

from dataclasses import dataclass
import logging
import os
import re
from typing import Callable, Optional

import numpy as np

from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.deformation.force import ForceEstimate
from pointforce_ros.deformation.fusion import FusionData
from pointforce_ros.deformation.mesh import MAX_MESH_NODES, TetMesh
from pointforce_ros.errors import check_npz_size, DataError, InvalidInput, reading
from pointforce_ros.model.files import QUARANTINE, quarantine_file
from pointforce_ros.types import as_array

FORMAT = 1
"""Version of the file layout (not the model version)."""

_NAME = re.compile(r'^deformation-v(\d+)\.npz$')
_QUARANTINED = re.compile(r'^deformation-v(\d+)\.npz')
MAX_YOUNG = 1e12
"""Largest Young's modulus believed in a file, Pa (diamond is about 1.1e12)."""
MIN_YOUNG = 1.0
"""Smallest Young's modulus believed in a file, Pa (the softest gels are about 10 Pa; at
1e-300 the stiffness underflows and every estimate failed in the SVD)."""
MAX_YOUNG_CONTRAST = 1e6
"""Largest ratio of element moduli in one file (bone in soft tissue is about 1e4)."""
POISSON_RANGE = (-0.5, 0.49)
"""Poisson ratios believed in a file (the identification searches 0-0.49): linear tetrahedra
lock towards 0.5 (nu 0.4999999999 answered 1209 N where 0.3 answered 4.3 N) and the shear
modulus diverges towards -1 (-0.9999999999: 5.4e9 N)."""
MAX_OFFSET = 0.1
"""Largest rest offset believed, metres (the pairing keeps offsets within a few mm)."""
MAX_LOAD_RADIUS = 1.0
"""Largest load patch radius believed, metres."""
MAX_SPREAD = 1e3
"""Largest relative FEM spread believed (the cell's objects measured 0.07-0.33)."""
MAX_COORDINATE = 100.0
"""Largest coordinate of a stored probe tip, metres (a cell is a few metres across)."""
MAX_FILE_BYTES = 256 << 20
"""Largest uncompressed content of a model file, bytes, checked before any array is read (a
compressed file of a few MB can hold gigabytes of zeros). A mesh of
:data:`.mesh.MAX_MESH_NODES` nodes takes about 10 MB."""
LOG = logging.getLogger(__name__)


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


def _highest_version(folder: str) -> int:
    """Highest version in ``folder`` and in its quarantine (0 when none)."""
    highest = max(model_versions(folder), default=0)
    quarantine = os.path.join(folder, QUARANTINE)
    if os.path.isdir(quarantine):
        found = [int(m.group(1)) for m in map(_QUARANTINED.match, os.listdir(quarantine)) if m]
        highest = max(highest, max(found, default=0))
    return highest


def save_model(folder: str, model: DeformationModel) -> str:
    """Write ``model`` atomically as the next version in ``folder``; return the path.

    The next version is above every one in ``folder`` and in its quarantine. The content is
    checked as :func:`load_model` checks it first: a model that would not load back (and be
    quarantined at the next start) is never written.

    Raises:
        DataError: content :func:`load_model` would refuse (nothing is written), or the
            folder cannot be created or written.

    """
    m = model.mesh
    fusion = {}
    if model.fusion is not None:
        f = model.fusion
        fusion = dict(fusion_spread=f.fem_spread, fusion_source=np.str_(f.spread_source),
                      fusion_tips=f.tips, fusion_forces=f.forces, fusion_sites=f.sites,
                      fusion_errors=f.errors, fusion_seconds=f.seconds)
    arrays = {k: np.asarray(v) for k, v in dict(
        format=FORMAT, nodes=m.nodes, tets=m.tets, fixed_nodes=m.fixed_nodes,
        surface_triangles=m.surface_triangles, element_size=m.element_size,
        young=np.asarray(model.young, dtype=float), poisson=model.poisson,
        rest_offset=model.rest_offset, load_radius=model.load_radius,
        residual_rms=model.residual_rms, **fusion).items()}
    try:
        _model_from_arrays(dict(arrays, version=np.asarray(1)))
    except (InvalidInput, KeyError, TypeError, ValueError) as exc:
        raise DataError(f'not saving the deformation model in {folder}: it would not load '
                        f'back ({exc})') from exc
    try:
        os.makedirs(folder, exist_ok=True)
        version = _highest_version(folder) + 1
        path = os.path.join(folder, f'deformation-v{version}.npz')
        tmp = os.path.join(folder, f'.deformation-v{version}.tmp.npz')
        np.savez_compressed(tmp, version=version, **arrays)
        os.replace(tmp, path)
    except OSError as exc:
        raise DataError(f'cannot save the deformation model in {folder}: {exc}')
    return path


def load_model(path: str) -> DeformationModel:
    """Read a model file and check its content (:func:`_model_from_arrays`).

    Raises:
        DataError: missing, unreadable, of another file format, or content no FEM can use
            (the message names the file and the array).

    """
    with reading(path, 'deformation model'):
        with np.load(path, allow_pickle=False) as data:
            check_npz_size(data, path, 'deformation model', MAX_FILE_BYTES)
            d = dict(data)
        fmt = d.get('format')
        if fmt is None or np.ndim(fmt) != 0 or fmt.dtype.kind not in 'iu' or int(fmt) != FORMAT:
            found = None if fmt is None else fmt.tolist()
            raise DataError(f'{path}: deformation model format {found!r} is not {FORMAT}')
        try:
            model = _model_from_arrays(d)
        except InvalidInput as exc:
            raise DataError(f'{path}: invalid deformation model: {exc}') from exc
        named = _NAME.match(os.path.basename(str(path)))
        if named is not None and int(named.group(1)) != model.version:
            raise DataError(f'{path}: version {model.version} in the file is not the one in '
                            f'its name ({int(named.group(1))})')
        return model


def _integer_array(d: dict, name: str, columns: Optional[int], n_nodes: int) -> np.ndarray:
    """``d[name]`` as node indices: an integer array, (K, columns) or (K,), all in range.

    Raises:
        InvalidInput: another dtype or shape, or an index outside ``0..n_nodes - 1``.

    """
    a = np.asarray(d[name])
    shape = '(K,)' if columns is None else f'(K, {columns})'
    if a.dtype.kind not in 'iu' or a.ndim != (1 if columns is None else 2) or (
            columns is not None and a.shape[1] != columns):
        raise InvalidInput(f'{name}: expected integer node indices of shape {shape}, got '
                           f'{a.dtype} {a.shape}')
    if a.size and (a.min() < 0 or a.max() >= n_nodes):
        raise InvalidInput(f'{name}: node index {int(a.min() if a.min() < 0 else a.max())} '
                           f'outside 0..{n_nodes - 1}')
    return a


def _scalar(d: dict, name: str, ok: Callable[[float], bool], wanted: str) -> float:
    """``d[name]`` as a finite real number for which ``ok`` holds.

    Raises:
        InvalidInput: not a real scalar, or ``ok`` refuses it (``wanted`` says what is).

    """
    a = np.asarray(d[name])
    if a.ndim != 0 or a.dtype.kind not in 'iuf' or not ok(float(a)):
        raise InvalidInput(f'{name}: must be {wanted}, got {a.tolist()!r}')
    return float(a)


def _mesh_from_arrays(d: dict) -> TetMesh:
    """Build the checked volume mesh of a file's arrays.

    Raises:
        InvalidInput: nodes not a finite (N, 3) array, tetrahedra not integer (M, 4) node
            indices in range with positive volume, bad fixed nodes or surface triangles, or
            an element size that is not a positive length.

    """
    nodes = np.asarray(d['nodes'])
    if nodes.dtype.kind not in 'iuf' or nodes.ndim != 2 or nodes.shape[1] != 3 or not len(nodes):
        raise InvalidInput(f'nodes: expected a (N, 3) array of positions, got {nodes.dtype} '
                           f'{nodes.shape}')
    nodes = nodes.astype(np.float64)
    bad = int(np.count_nonzero(~np.isfinite(nodes).all(axis=1)))
    if bad:
        raise InvalidInput(f'nodes: {bad} node(s) with a non-finite position')
    n = len(nodes)
    if n > MAX_MESH_NODES:
        raise InvalidInput(f'nodes: {n} nodes, more than a mesh of this node may have '
                           f'({MAX_MESH_NODES})')
    tets = _integer_array(d, 'tets', 4, n)
    if not len(tets):
        raise InvalidInput('tets: no tetrahedra')
    fixed = _integer_array(d, 'fixed_nodes', None, n)
    held = nodes[np.unique(fixed)]
    if len(held) < 3 or np.linalg.matrix_rank(held - held.mean(axis=0), tol=1e-9) < 2:
        raise InvalidInput(f'fixed_nodes: {len(held)} node(s) on one line or fewer than 3: '
                           f'the model would float freely (no support on the table)')
    triangles = _integer_array(d, 'surface_triangles', 3, n)
    if not len(triangles):
        raise InvalidInput('surface_triangles: none (no surface a camera or a probe can see)')
    mesh = TetMesh(nodes=nodes, tets=tets, fixed_nodes=fixed, surface_triangles=triangles,
                   element_size=_scalar(d, 'element_size', lambda v: np.isfinite(v) and v > 0,
                                        'a positive length in metres'))
    flat = int(np.count_nonzero(~(mesh.volumes() > 0)))
    if flat:
        raise InvalidInput(f'tets: {flat} of {len(tets)} tetrahedra with a volume that is not '
                           f'positive (inverted or degenerate)')
    return mesh


def _fusion_from_arrays(d: dict) -> Optional[FusionData]:
    """Return the fused force's data of a file (None in files from before it).

    Raises:
        InvalidInput: a non-finite or negative spread, or arrays of inconsistent sizes.

    """
    if 'fusion_spread' not in d:   # older files have none: the fused force then uses defaults
        return None
    spread = _scalar(d, 'fusion_spread', lambda v: 0 <= v <= MAX_SPREAD,
                     f'a relative spread in [0, {MAX_SPREAD:g}]')
    tips = np.asarray(d['fusion_tips'], dtype=np.float64)
    forces = np.asarray(d['fusion_forces'], dtype=np.float64)
    sites = np.asarray(d['fusion_sites'])
    errors = np.asarray(d['fusion_errors'], dtype=np.float64)
    source = np.asarray(d['fusion_source'])
    if tips.ndim != 2 or tips.shape[1] != 3 or forces.shape != (len(tips),) or (
            sites.shape != (len(tips),)):
        raise InvalidInput(f'fusion: tips {tips.shape}, forces {forces.shape} and sites '
                           f'{sites.shape} are not (n, 3), (n,), (n,)')
    finite = np.isfinite(tips)
    if not (np.all(finite.all(axis=1) | np.isnan(tips).all(axis=1))
            and np.all(np.abs(tips[finite]) <= MAX_COORDINATE)):
        raise InvalidInput(f'fusion_tips: each tip must be a position within '
                           f'{MAX_COORDINATE:g} m or all NaN (a push without one)')
    if not (np.all(np.isfinite(forces)) and np.all(forces >= 0)):
        raise InvalidInput('fusion_forces: every F/T magnitude must be finite and >= 0')
    if sites.dtype.kind not in 'iu':
        raise InvalidInput(f'fusion_sites: expected integer site labels, got {sites.dtype}')
    if errors.ndim != 1 or not np.all(np.isfinite(errors)):
        raise InvalidInput(f'fusion_errors: expected (k,) finite log errors, got '
                           f'{errors.shape}')
    if source.ndim != 0 or source.dtype.kind != 'U':
        raise InvalidInput(f'fusion_source: expected one string, got {source.dtype} '
                           f'{source.shape}')
    return FusionData(fem_spread=spread, spread_source=str(source), tips=tips,
                      forces=forces, sites=sites, errors=errors,
                      seconds=_scalar(d, 'fusion_seconds', np.isfinite, 'finite seconds'))


def _model_from_arrays(d: dict) -> DeformationModel:
    """Build the checked model from the arrays of its file (a missing one raises KeyError).

    Raises:
        InvalidInput: content the FEM or the force estimate cannot use (see :func:`load_model`).

    """
    mesh = _mesh_from_arrays(d)
    young = np.asarray(d['young'])
    if young.dtype.kind not in 'iuf' or young.shape not in ((), (len(mesh.tets),)):
        raise InvalidInput(f'young: expected a modulus or ({len(mesh.tets)},) per element, '
                           f'got {young.dtype} {young.shape}')
    young = young.astype(np.float64)
    if not (np.all(np.isfinite(young)) and np.all(young >= MIN_YOUNG)
            and np.all(young <= MAX_YOUNG)):
        raise InvalidInput(f'young: every modulus must be in [{MIN_YOUNG:g}, {MAX_YOUNG:g}] Pa, '
                           f'got {young.min():g} .. {young.max():g}')
    if young.max() > MAX_YOUNG_CONTRAST * young.min():
        raise InvalidInput(f'young: element moduli {young.min():g} .. {young.max():g} Pa differ '
                           f'by more than a factor {MAX_YOUNG_CONTRAST:g}')
    rest_offset = np.asarray(d['rest_offset'])
    if rest_offset.dtype.kind not in 'iuf' or rest_offset.shape != (mesh.n_nodes,) or not (
            np.all(np.abs(rest_offset) <= MAX_OFFSET)):
        raise InvalidInput(f'rest_offset: expected ({mesh.n_nodes},) finite offsets within '
                           f'{MAX_OFFSET:g} m, got {rest_offset.dtype} {rest_offset.shape}')
    version = np.asarray(d['version'])
    if version.ndim != 0 or version.dtype.kind not in 'iu' or int(version) < 1:
        raise InvalidInput(f'version: must be a whole number >= 1, got {version.tolist()!r}')
    return DeformationModel(
        mesh=mesh, young=float(young) if young.ndim == 0 else young,
        poisson=_scalar(d, 'poisson', lambda v: POISSON_RANGE[0] <= v <= POISSON_RANGE[1],
                        f'a Poisson ratio in [{POISSON_RANGE[0]:g}, {POISSON_RANGE[1]:g}]'),
        rest_offset=rest_offset.astype(np.float64),
        load_radius=_scalar(d, 'load_radius', lambda v: 0 < v <= MAX_LOAD_RADIUS,
                            f'a length in (0, {MAX_LOAD_RADIUS:g}] metres'),
        residual_rms=_scalar(d, 'residual_rms', lambda v: np.isnan(v) or 0 <= v < np.inf,
                             'an rms >= 0 in metres (NaN: not known)'),
        version=int(version), fusion=_fusion_from_arrays(d))


def load_latest(folder: str, log: Optional[Callable[[str], None]] = None
                ) -> Optional[DeformationModel]:
    """Return the newest valid model in ``folder``, or None when there is none.

    A file that cannot be loaded (:func:`load_model`) is moved to ``quarantine/`` beside it
    with a ``.reason.txt`` (:func:`~pointforce_ros.model.files.quarantine_file`) and the next
    older version is tried: a corrupt newest file never hides an older valid one. A bad file
    that cannot be moved (a read-only folder) is skipped and reported.

    Args:
        folder: the model folder.
        log: called with one message per quarantined or skipped file (a node's logger).

    """
    for version in reversed(model_versions(folder)):
        path = os.path.join(folder, f'deformation-v{version}.npz')
        try:
            return load_model(path)
        except DataError as exc:
            try:
                moved = quarantine_file(path, str(exc))
                note = (None if moved is None else
                        f'quarantined {os.path.basename(path)} as {moved}: {exc}')
            except OSError as move_error:
                note = (f'skipping {os.path.basename(path)} ({exc}); cannot quarantine it: '
                        f'{move_error}')
                LOG.error(note)
            if log is not None and note is not None:
                log(note)
    return None


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
