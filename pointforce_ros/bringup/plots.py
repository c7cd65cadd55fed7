"""PNG figures a person looks at: force curves with the model, stiffness map, deformed surface.

Matplotlib with the Agg backend (no display needed). Every function writes one PNG and returns
its path; units on the axes are millimetres and newtons.
"""

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from pointforce_ros.types import Surface


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _nearest(surface: Surface, points: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree
    return cKDTree(surface.points).query(np.atleast_2d(points))[1]


def plot_force_curves(curves: Sequence, model, surface: Surface, path, *,
                      max_curves: int = 8, title: str = 'Force response: measured and learned'
                      ) -> Path:
    """Measured loading curves (dots) and the model's prediction at each poke point (lines).

    ``curves`` are :class:`~pointforce_ros.pokes.curves.PokeCurve`; ``model`` any force-response
    model with ``predict`` (and ``predict_std`` for a band, if it has one).
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 5))
    colours = plt.cm.viridis(np.linspace(0, 0.9, min(len(curves), max_curves)))
    for curve, colour in zip(list(curves)[:max_curves], colours):
        idx = _nearest(surface, curve.point)[0]
        ax.plot(1e3 * curve.d[::3], curve.f[::3], '.', ms=2.5, color=colour, alpha=0.6)
        d = np.linspace(curve.d.min(), curve.d.max(), 120)
        feats = np.repeat(surface.features[idx][None], len(d), axis=0)
        f = model.predict(feats, d)
        ax.plot(1e3 * d, f, '-', lw=1.8, color=colour, label=curve.poke_id)
        std = model.predict_std(feats, d) if hasattr(model, 'predict_std') else None
        if std is not None:
            ax.fill_between(1e3 * d, f - 2 * std, f + 2 * std, color=colour, alpha=0.12)
    ax.set_xlabel('displacement d along -n (mm)')
    ax.set_ylabel('normal force f (N)')
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc='upper left')
    return _save(fig, path)


def plot_stiffness_map(surface: Surface, forces: np.ndarray, path, *, depth: float,
                       pokes: Optional[np.ndarray] = None, truth: Optional[np.ndarray] = None,
                       title: str = 'Learned force at depth') -> Path:
    """Top view of the surface coloured by the force (N) at ``depth`` (m); pokes as crosses.

    With ``truth`` (N,) a second panel shows the ground truth on the same colour scale. Only
    points facing up (normal within 45 deg of +z) are drawn: a side face seen from above is a
    line, and a probe pushed "down" there is deep inside the object.
    """
    plt = _plt()
    up = surface.normals[:, 2] >= np.cos(np.pi / 4)
    panels = 2 if truth is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(6.4 * panels, 4.8), squeeze=False)
    shown = [np.asarray(v, dtype=float)[up] for v in (forces, truth) if v is not None]
    vmax = float(np.nanmax(np.concatenate(shown))) if np.any(up) else 1.0
    for ax, values, name in zip(axes[0], [forces, truth], ['learned', 'ground truth']):
        if values is None:
            continue
        sc = ax.scatter(1e3 * surface.points[up, 0], 1e3 * surface.points[up, 1],
                        c=np.asarray(values, dtype=float)[up], s=4, cmap='magma', vmin=0.0,
                        vmax=vmax)
        if pokes is not None and len(pokes):
            ax.plot(1e3 * pokes[:, 0], 1e3 * pokes[:, 1], 'x', color='cyan', ms=7, mew=2,
                    label='pokes')
            ax.legend(loc='upper right', fontsize=8)
        ax.set_aspect('equal')
        ax.set_xlabel('x (mm, base)')
        ax.set_ylabel('y (mm, base)')
        ax.set_title(f'{title} {1e3 * depth:.1f} mm: {name}', fontsize=10)
        fig.colorbar(sc, ax=ax, label='force (N)')
    return _save(fig, path)


def plot_deformed_surface(surface: Surface, displacement: np.ndarray, path, *,
                          rigid_points: Optional[np.ndarray] = None,
                          title: str = 'Deformed surface') -> Path:
    """Surface coloured by displacement (mm), seen from above and from the side (y-z).

    ``displacement`` (N,) metres along ``-n``; the deformed points are ``p - u n``.
    """
    plt = _plt()
    deformed = surface.points - displacement[:, None] * surface.normals
    fig, (top, side) = plt.subplots(1, 2, figsize=(12, 4.8))
    sc = top.scatter(1e3 * deformed[:, 0], 1e3 * deformed[:, 1], c=1e3 * displacement, s=4,
                     cmap='plasma')
    top.set_aspect('equal')
    top.set_xlabel('x (mm)')
    top.set_ylabel('y (mm)')
    top.set_title(f'{title}: top view')
    fig.colorbar(sc, ax=top, label='displacement (mm)')
    band = np.abs(deformed[:, 0] - np.average(deformed[:, 0], weights=displacement + 1e-9)) < 0.003
    side.scatter(1e3 * surface.points[band, 1], 1e3 * surface.points[band, 2], s=3, c='0.7',
                 label='equilibrium')
    side.scatter(1e3 * deformed[band, 1], 1e3 * deformed[band, 2], s=4,
                 c=1e3 * displacement[band], cmap='plasma', label='deformed')
    if rigid_points is not None and len(rigid_points):
        side.plot(1e3 * rigid_points[:, 1], 1e3 * rigid_points[:, 2], '.', ms=3, color='k',
                  label='rigid body samples')
    side.set_aspect('equal')
    side.set_xlabel('y (mm)')
    side.set_ylabel('z (mm)')
    side.set_title('section through the contact (|x - x_c| < 3 mm)')
    side.legend(fontsize=8)
    return _save(fig, path)


def plot_wrench_pred_vs_true(names: Sequence[str], pred: np.ndarray, std: np.ndarray,
                             true: np.ndarray, path, *, level_sigma: float = 1.6448536269514722,
                             title: str = 'Contact wrench: predicted against true') -> Path:
    """Predicted against true normal force ``Fz`` and torque norm per query, with intervals.

    ``pred``, ``std``, ``true`` are (Q, 6) ``[fx, fy, fz, tx, ty, tz]`` (N, N m); the bars are
    ``+- level_sigma * std`` (1.645: nominal 90 %). Left: ``Fz`` against its truth with the
    identity line; right: the error ``Fz - Fz_true`` per query with its bar (a bar that
    misses zero is a miss of the interval).
    """
    plt = _plt()
    pred, std, true = (np.asarray(a, dtype=float) for a in (pred, std, true))
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5))
    kinds = sorted({n.split(' #')[0] for n in names})
    colours = dict(zip(kinds, plt.cm.tab10(np.arange(len(kinds)))))
    for i, name in enumerate(names):
        kind = name.split(' #')[0]
        label = kind if name.endswith('#1') or ' #' not in name else None
        left.errorbar(true[i, 2], pred[i, 2], yerr=level_sigma * std[i, 2], fmt='o',
                      color=colours[kind], capsize=3, label=label)
        right.errorbar(i, pred[i, 2] - true[i, 2], yerr=level_sigma * std[i, 2], fmt='o',
                       color=colours[kind], capsize=3)
    top = 1.1 * float(max(true[:, 2].max(), (pred[:, 2] + level_sigma * std[:, 2]).max()))
    left.plot([0, top], [0, top], 'k--', lw=1, label='predicted = true')
    left.set_xlim(0, top)
    left.set_ylim(0, top)
    left.set_xlabel('true Fz (N, FEM full solve)')
    left.set_ylabel('predicted Fz (N, contact service)')
    left.set_title(title)
    left.legend(fontsize=8, loc='upper left')
    left.grid(alpha=0.3)
    right.axhline(0.0, color='k', lw=1)
    right.set_xticks(range(len(names)))
    right.set_xticklabels(names, rotation=40, ha='right', fontsize=8)
    right.set_ylabel('Fz error, predicted - true (N)')
    inside = np.abs(pred[:, 2] - true[:, 2]) <= level_sigma * std[:, 2]
    right.set_title(f'error with nominal 90 % intervals: {int(inside.sum())}/{len(names)} '
                    'cover the truth')
    right.grid(alpha=0.3)
    return _save(fig, path)


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path
