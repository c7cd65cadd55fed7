"""Object definitions of the simulated cell: geometry, stiffness field, colour pattern.

Objects are YAML files in ``config/objects/`` (see ``plush.yaml`` for every field). An object
rests on the table (``z = 0`` is the table top) centred at ``geometry.centre`` (x, y), with its top
near ``z = 0.04`` m. All lengths are metres, moduli pascals, forces newtons, frame ``base``.

The stiffness field is ground truth for plots and for the FEM; the colour pattern is what the
camera sees: it correlates with stiffness the way a real object's does (a bone shows through,
a stiff panel has another fabric) but not perfectly (offset patches, stains, noise).
"""

from dataclasses import dataclass, field
import os
from typing import List, Mapping, Optional, Tuple

import numpy as np
import yaml

from pointforce_ros.sim.fem.mesh import (graded_axis, HexMesh, replace_nodes, square_to_disk,
                                         structured_hex)
from pointforce_ros.paths import share_path
from pointforce_ros.errors import DataError, InvalidInput, reading, TEXT_ENCODING
from pointforce_ros.types import as_array, Mesh
from pointforce_ros.sim.fem.hyperelastic import GAUSS_2, shape_functions

OBJECTS_DIR = str(share_path('config', 'objects'))
"""Folder of the shipped object YAML files."""


def _smooth_step(signed: np.ndarray, width: float) -> np.ndarray:
    """1 inside (signed < 0), 0 outside, a smooth ramp of ``width`` metres across the boundary."""
    if width <= 0:
        return (signed <= 0).astype(float)
    return 0.5 * (1.0 - np.tanh(signed / (0.5 * width)))


@dataclass(frozen=True)
class Region:
    """A material or colour region.

    ``kind`` is ``ellipsoid`` (``centre`` (3,), ``radii`` (3,)), ``box`` (``lo`` (3,), ``hi``
    (3,)), ``layer`` (``depth`` = (top, bottom) measured down from the local top surface, or
    ``z`` = (lo, hi) above the table), or ``ellipse`` (colour only: ``centre`` (2,), ``radii``
    (2,), in x-y). ``value`` is the Young's modulus (Pa) or the RGB (3,) in [0, 1].
    """

    kind: str
    params: Mapping
    value: object
    blend: float = 0.0


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the simulated cell (frozen; built by :func:`load_object`).

    Attributes:
        name: object name (file stem).
        kind: ``box`` or ``dome``.
        size: (3,) footprint length x, width y, height z of the body, metres.
        centre: (2,) footprint centre (x, y), metres, ``base``.
        rim_height: dome height at the rim, metres (dome only).
        undulation: ``(amplitude, (wavelength_x, wavelength_y), (phase_x, phase_y))`` of the top.
        young: base Young's modulus, Pa.
        poisson: Poisson ratio.
        regions: material regions applied in order.
        colour_base: (3,) base RGB.
        colour_regions: colour patches applied in order.
        colour_noise: amplitude of the seeded stain pattern.
        colour_seed: seed of the stain pattern.
        mesh_validation: element size near the probe for validation solves, metres.
        mesh_live: element size near the probe for the live-path cache, metres.
        force_cap: poke force limit, newtons.
        max_depth: poke depth limit, metres.
        live_grid: (nx, ny) poke locations of the live-path cache.
        support: ``fixed`` or ``sliding``.
        description: free text.

    """

    name: str
    kind: str
    size: Tuple[float, float, float]
    centre: Tuple[float, float]
    rim_height: float
    undulation: Tuple
    young: float
    poisson: float
    regions: Tuple[Region, ...]
    colour_base: Tuple[float, float, float]
    colour_regions: Tuple[Region, ...]
    colour_noise: float
    colour_seed: int
    mesh_validation: float
    mesh_live: float
    force_cap: float
    max_depth: float
    live_grid: Tuple[int, int]
    support: str = 'fixed'
    description: str = ''
    source: Optional[str] = field(default=None, compare=False)

    # -- geometry --------------------------------------------------------------------------
    def footprint_mask(self, x, y) -> np.ndarray:
        """Boolean (..,) whether (x, y) lies over the object's footprint."""
        u, v = self._uv(x, y)
        if self.kind == 'dome':
            return u * u + v * v <= 1.0
        return (np.abs(u) <= 1.0) & (np.abs(v) <= 1.0)

    def _uv(self, x, y):
        return ((np.asarray(x, dtype=float) - self.centre[0]) / (self.size[0] / 2),
                (np.asarray(y, dtype=float) - self.centre[1]) / (self.size[1] / 2))

    def top_height(self, x, y) -> np.ndarray:
        """Undeformed top-surface height z (metres) over (x, y) (clipped to the footprint)."""
        u, v = self._uv(x, y)
        if self.kind == 'dome':
            rho2 = np.clip(u * u + v * v, 0.0, 1.0)
            z = self.rim_height + (self.size[2] - self.rim_height) * (1.0 - rho2)
        else:
            z = np.full(np.broadcast(u, v).shape, self.size[2])
        amp, wave, phase = self.undulation
        if amp:
            x = np.asarray(x, dtype=float)
            y = np.asarray(y, dtype=float)
            z = z + amp * np.sin(2 * np.pi * x / wave[0] + phase[0]) * np.sin(
                2 * np.pi * y / wave[1] + phase[1])
        return z

    @property
    def top_bound(self) -> float:
        """Height (metres) no point of the undeformed top surface lies above."""
        return float(max(self.size[2], self.rim_height) + abs(self.undulation[0]))

    def top_normal(self, x, y) -> np.ndarray:
        """(..., 3) outward unit normal of the undeformed top surface at (x, y)."""
        e = 1e-5
        gx = (self.top_height(np.asarray(x) + e, y) - self.top_height(np.asarray(x) - e, y)) / (
            2 * e)
        gy = (self.top_height(x, np.asarray(y) + e) - self.top_height(x, np.asarray(y) - e)) / (
            2 * e)
        n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def top_point(self, x, y) -> np.ndarray:
        """(..., 3) undeformed top-surface point above (x, y), metres."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        return np.stack(np.broadcast_arrays(x, y, self.top_height(x, y)), -1)

    def build_mesh(self, h: float, refine_at=None, fine_radius=0.008,
                   growth: float = 1.3, h_max: Optional[float] = None,
                   h_z: Optional[float] = None) -> HexMesh:
        """Hexahedral mesh of the body.

        Args:
            h: element size (uniform, or near ``refine_at`` when given), metres.
            refine_at: (2,) x, y to refine around; ``None`` for a uniform mesh.
            fine_radius: half-width of the fine zone, metres, or (x, y) half-widths.
            growth: element growth factor away from the fine zone.
            h_max: largest element size, metres (default 4 h).
            h_z: element size through the thickness at the top (default ``h``).

        Raises:
            InvalidInput: non-positive sizes.

        """
        if not h > 0:
            raise InvalidInput(f'build_mesh: element size must be positive, got {h}')
        h_max = h_max or 4 * h
        h_z = h_z or h
        lx, ly, lz = self.size
        if refine_at is None:
            s = graded_axis(-1.0, 1.0, 2 * h / lx)
            t = graded_axis(-1.0, 1.0, 2 * h / ly)
        else:
            u0, v0 = self._uv(refine_at[0], refine_at[1])
            if self.kind == 'dome':
                u0, v0 = _disk_to_square(u0, v0)
            rx, ry = np.broadcast_to(np.asarray(fine_radius, dtype=float), (2,))
            s = graded_axis(-1.0, 1.0, 2 * h / lx, u0, 2 * rx / lx, growth, 2 * h_max / lx)
            t = graded_axis(-1.0, 1.0, 2 * h / ly, v0, 2 * ry / ly, growth, 2 * h_max / ly)
        fz = float(np.min(fine_radius))
        zeta = graded_axis(0.0, 1.0, h_z / lz, 1.0, fz / lz, growth, h_max / lz)
        mesh = structured_hex(s, t, zeta)
        u, v, w = mesh.nodes.T
        if self.kind == 'dome':
            u, v = square_to_disk(u, v)
        x = self.centre[0] + u * lx / 2
        y = self.centre[1] + v * ly / 2
        z = w * self.top_height(x, y)
        return replace_nodes(mesh, np.stack([x, y, z], -1))

    # -- material and colour ---------------------------------------------------------------
    def stiffness_at(self, points) -> np.ndarray:
        """Ground-truth Young's modulus (N,) in Pa at (N, 3) points, metres, ``base``.

        Raises:
            InvalidInput: points not of shape (N, 3) or not finite.

        """
        p = as_array(points, 'points', (None, 3))
        e = np.full(len(p), float(self.young))
        top = self.top_height(p[:, 0], p[:, 1])
        for reg in self.regions:
            s = _smooth_step(_signed_distance(reg, p, top), reg.blend)
            e = e * (1.0 - s) + float(reg.value) * s
        return e

    def colour_at(self, points) -> np.ndarray:
        """RGB (N, 3) in [0, 1] of the visible surface at (N, 3) points (seeded, repeatable)."""
        p = as_array(points, 'points', (None, 3))
        rgb = np.tile(np.asarray(self.colour_base, dtype=float), (len(p), 1))
        top = self.top_height(p[:, 0], p[:, 1])
        for reg in self.colour_regions:
            s = _smooth_step(_signed_distance(reg, p, top), reg.blend)[:, None]
            rgb = rgb * (1.0 - s) + np.asarray(reg.value, dtype=float) * s
        if self.colour_noise:
            rng = np.random.default_rng(self.colour_seed)
            k = rng.normal(size=(6, 2)) * 2 * np.pi / 0.02
            ph = rng.uniform(0, 2 * np.pi, 6)
            amp = rng.normal(size=(6, 3))
            waves = np.sin(p[:, :2] @ k.T + ph) / np.sqrt(6)  # (N, 6)
            rgb = rgb + self.colour_noise * waves @ amp
        return np.clip(rgb, 0.0, 1.0)

    def surface_mesh(self, h: float = 0.002) -> Tuple[Mesh, np.ndarray]:
        """Visible surface (top and sides, not the bottom on the table) for the camera.

        Args:
            h: triangle edge length, metres.

        Returns:
            ``(mesh, rgb)``: a ``types.Mesh`` in ``base`` with outward winding, and per-vertex
            RGB (V, 3) in [0, 1].

        """
        mesh = self.build_mesh(h, h_z=max(h, self.size[2] / 8))
        faces = mesh.boundary_faces
        used, inv = np.unique(faces, return_inverse=True)
        quads = inv.reshape(faces.shape)
        tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        verts = mesh.nodes[used]
        return Mesh(verts, tris), self.colour_at(verts)

    def gauss_young(self, mesh: HexMesh) -> np.ndarray:
        """(E, 8) Young's modulus at the 2x2x2 Gauss points of ``mesh``, Pa."""
        n = shape_functions(GAUSS_2)  # (8, 8)
        pts = np.einsum('qa,eai->eqi', n, mesh.nodes[mesh.elements]).reshape(-1, 3)
        return self.stiffness_at(pts).reshape(-1, 8)


def _disk_to_square(x, y):
    """Approximate inverse of :func:`square_to_disk` (Newton, a few iterations)."""
    u, v = float(x), float(y)
    for _ in range(20):
        fu, fv = square_to_disk(u, v)
        ju = np.array([[np.sqrt(1 - 0.5 * v * v), -u * v / (2 * np.sqrt(1 - 0.5 * v * v))],
                       [-u * v / (2 * np.sqrt(1 - 0.5 * u * u)), np.sqrt(1 - 0.5 * u * u)]])
        du, dv = np.linalg.solve(ju, [fu - x, fv - y])
        u, v = float(np.clip(u - du, -1, 1)), float(np.clip(v - dv, -1, 1))
    return u, v


def _signed_distance(reg: Region, p: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Approximate signed distance (m, negative inside) of points to a region."""
    q = reg.params
    if reg.kind == 'ellipsoid':
        c, r = np.asarray(q['centre'], float), np.asarray(q['radii'], float)
        rho = np.linalg.norm((p - c) / r, axis=1)
        return (rho - 1.0) * r.min()
    if reg.kind == 'ellipse':
        c, r = np.asarray(q['centre'], float), np.asarray(q['radii'], float)
        rho = np.linalg.norm((p[:, :2] - c) / r, axis=1)
        return (rho - 1.0) * r.min()
    if reg.kind == 'box':
        lo, hi = np.asarray(q['lo'], float), np.asarray(q['hi'], float)
        return np.max(np.maximum(lo - p, p - hi), axis=1)
    if reg.kind == 'layer':
        if 'depth' in q:
            d0, d1 = q['depth']
            depth = top - p[:, 2]
            return np.maximum(d0 - depth, depth - d1)
        z0, z1 = q['z']
        return np.maximum(z0 - p[:, 2], p[:, 2] - z1)
    raise InvalidInput(f'region kind {reg.kind!r} unknown (ellipsoid, ellipse, box, layer)')


def _regions(items, colour: bool) -> Tuple[Region, ...]:
    out: List[Region] = []
    for i, item in enumerate(items or []):
        item = dict(item)
        kind = item.pop('kind', None)
        key = 'rgb' if colour else 'young'
        if kind is None or key not in item:
            raise InvalidInput(f'region {i}: needs "kind" and "{key}"')
        value = item.pop(key)
        blend = float(item.pop('blend', 0.0))
        region = Region(kind=kind, params=item, value=value, blend=blend)
        _signed_distance(region, np.zeros((1, 3)), np.zeros(1))  # validates the kind
        if colour and (len(value) != 3 or min(value) < 0 or max(value) > 1):
            raise InvalidInput(f'colour region {i}: rgb must be 3 values in [0, 1]')
        if not colour and not float(value) > 0:
            raise InvalidInput(f'material region {i}: young must be positive')
        out.append(region)
    return tuple(out)


def list_objects() -> List[str]:
    """Names of the shipped objects (``config/objects/*.yaml``), sorted."""
    if not os.path.isdir(OBJECTS_DIR):
        return []
    return sorted(f[:-5] for f in os.listdir(OBJECTS_DIR) if f.endswith('.yaml'))


def _section(doc: Mapping, key: str, path: str, required: bool = False,
             label: Optional[str] = None) -> Mapping:
    """Return the mapping ``doc[key]`` (``{}`` when absent and not ``required``).

    ``label`` names the section in messages (default ``key``).

    Raises:
        InvalidInput: the section is missing (``required``) or not a mapping; the message
            names the file and the section.

    """
    label = key if label is None else label
    if key not in doc or (doc[key] is None and not required):
        if required:
            raise InvalidInput(f'object file {path}: section {label!r} is missing')
        return {}
    section = doc[key]
    if not isinstance(section, Mapping):
        raise InvalidInput(f'object file {path}: section {label!r} must be a mapping (indented '
                           f'"name: value" lines), got {type(section).__name__} {section!r}')
    return section


def load_object(name_or_path: str) -> ObjectSpec:
    """Load an object by name (``plush``) or by path to a YAML file.

    Raises:
        DataError: no such object, or the file cannot be read as YAML.
        InvalidInput: a section that is not a mapping, a field missing or out of range (the
            message names the file and the section or field).

    """
    path = name_or_path
    if not os.path.isfile(path):
        path = os.path.join(OBJECTS_DIR, f'{name_or_path}.yaml')
    if not os.path.isfile(path):
        raise DataError(f'object {name_or_path!r} not found: known objects are '
                        f'{", ".join(list_objects())} (or give a path to a YAML file)')
    with reading(path, 'object file (YAML)'):
        with open(path, encoding=TEXT_ENCODING) as fh:
            doc = yaml.safe_load(fh)
    if not isinstance(doc, Mapping):
        raise InvalidInput(f'object file {path}: expected a mapping of sections (geometry, '
                           f'material, ...), got {type(doc).__name__}')
    geo, mat = _section(doc, 'geometry', path, True), _section(doc, 'material', path, True)
    col, mesh = _section(doc, 'colour', path), _section(doc, 'mesh', path)
    poke, live = _section(doc, 'poke', path), _section(doc, 'live', path)
    und = _section(geo, 'undulation', path, label='geometry.undulation')
    try:
        spec = ObjectSpec(
            name=str(doc.get('name', os.path.basename(path)[:-5])),
            kind=str(geo.get('kind', 'box')),
            size=tuple(float(v) for v in geo['size']),
            centre=tuple(float(v) for v in geo.get('centre', (0.5, 0.0))),
            rim_height=float(geo.get('rim_height', 0.0)),
            undulation=(float(und.get('amplitude', 0.0)),
                        tuple(float(v) for v in und.get('wavelength', (0.05, 0.05))),
                        tuple(float(v) for v in und.get('phase', (0.0, 0.0)))),
            young=float(mat['young']), poisson=float(mat.get('poisson', 0.45)),
            regions=_regions(mat.get('regions'), colour=False),
            colour_base=tuple(float(v) for v in col.get('base', (0.6, 0.6, 0.6))),
            colour_regions=_regions(col.get('patches'), colour=True),
            colour_noise=float(col.get('noise', 0.0)), colour_seed=int(col.get('seed', 0)),
            mesh_validation=float(mesh.get('validation', 0.0015)),
            mesh_live=float(mesh.get('live', 0.002)),
            force_cap=float(poke.get('force_cap', 5.0)),
            max_depth=float(poke.get('max_depth', 0.010)),
            live_grid=tuple(int(v) for v in live.get('grid', (5, 4))),
            support=str(geo.get('support', 'fixed')),
            description=str(doc.get('description', '')), source=path)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InvalidInput(f'object file {path}: missing or malformed field: '
                           f'{type(exc).__name__}: {exc}') from exc
    except InvalidInput as exc:     # a region's check: say which file
        raise InvalidInput(f'object file {path}: {exc}') from exc
    _validate(spec)
    return spec


MAX_SIZE = 0.5
"""Largest body length along any axis, metres (the cell's table; the camera mesh has
(size / 2 mm)^2 faces)."""

MESH_SIZES = (0.001, 0.01)
"""Range of ``mesh.validation`` and ``mesh.live``, metres: 1 mm grades a 20 000-element mesh
around the probe, 1e-9 m would ask for more elements than any memory holds."""

LIVE_GRID = (2, 15)
"""Range of each of ``live.grid``'s two counts: the live cache solves nx x ny nonlinear FEM
pokes (minutes each) and interpolates between them (at least 2 a side)."""


def _validate(spec: ObjectSpec):
    """Check the ranges of ``spec``; the messages name its file (when it has one).

    Raises:
        InvalidInput: a value out of range (the message names the key and its range).

    """
    who = spec.name if spec.source is None else f'object file {spec.source} ({spec.name})'
    if spec.kind not in ('box', 'dome'):
        raise InvalidInput(f'{who}: geometry.kind must be box or dome, got {spec.kind}')
    if len(spec.size) != 3 or not all(0 < v <= MAX_SIZE for v in spec.size):
        raise InvalidInput(f'{who}: geometry.size needs 3 lengths in (0, {MAX_SIZE:g}] m, got '
                           f'{spec.size}')
    if len(spec.centre) != 2 or not np.all(np.isfinite(spec.centre)):
        raise InvalidInput(f'{who}: geometry.centre needs 2 finite coordinates (m), got '
                           f'{spec.centre}')
    amp, wave, phase = spec.undulation
    if not (np.isfinite(amp) and len(wave) == 2 and all(v > 0 for v in wave)
            and len(phase) == 2 and np.all(np.isfinite(phase))
            and np.all(np.isfinite(wave))):
        raise InvalidInput(f'{who}: geometry.undulation needs a finite amplitude, 2 positive '
                           f'wavelengths and 2 phases, got {spec.undulation}')
    if spec.kind == 'dome' and not 0 < spec.rim_height < spec.size[2]:
        raise InvalidInput(f'{who}: dome needs 0 < rim_height < size[2]')
    if not spec.young > 0 or not -1 < spec.poisson < 0.5:
        raise InvalidInput(f'{who}: need young > 0 and -1 < poisson < 0.5, got young '
                           f'{spec.young:g} Pa, poisson {spec.poisson:g}')
    if not 0.5 <= spec.force_cap <= 30:
        raise InvalidInput(f'{who}: poke.force_cap {spec.force_cap} N out of 0.5..30')
    if not 0 < spec.max_depth <= spec.size[2]:
        raise InvalidInput(f'{who}: poke.max_depth {spec.max_depth} m out of (0, '
                           f'{spec.size[2]:g}] (the body height)')
    low, high = MESH_SIZES
    for key, value in (('mesh.live', spec.mesh_live), ('mesh.validation', spec.mesh_validation)):
        if not low <= value <= high:
            raise InvalidInput(f'{who}: {key} {value:g} m out of {low:g}..{high:g} m')
    low, high = LIVE_GRID
    if len(spec.live_grid) != 2 or not all(low <= n <= high for n in spec.live_grid):
        raise InvalidInput(f'{who}: live.grid needs 2 counts in {low}..{high}, got '
                           f'{list(spec.live_grid)}')
