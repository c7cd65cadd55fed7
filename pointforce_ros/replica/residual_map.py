"""Where one homogeneous replica fails: its held-out residual by depth, time, site and section.

A replica is one homogeneous neo-Hookean body. On a heterogeneous object (a stiff core in a
ball, the lamb's bone) it can match some measures and not others; this map says which, on the
held-out pokes only:

* by depth: the replica's force minus the measured one over the loading curve, % of each
  poke's peak, in thirds of the depth range (does it miss the start or the deep end?);
* by time: the force-time residual of each held-out poke, in phases: while the pusher moves
  and while it holds (a ramp-and-hold record), or in the first and second half of the loading
  (a loading curve alone): does it lack rate dependence or relaxation?
* by site: the signed error at each poke's largest depth against the poke's x-y (the probe's
  sites on a scanned object; one site for the plate on a ball);
* by section angle (a plate on a ball with a known section): the radial gap of the replica's
  loaded outline against the truth's (and the camera's) in 30-degree sectors about the
  deformed centre: where the shape under load fails.

:func:`residual_map` computes the numbers (JSON-able) and the curves; :func:`plot_residual_map`
draws them (matplotlib, Agg) into one PNG.
"""

from typing import Dict, Optional, Sequence

import numpy as np

from pointforce_ros.replica.calibrate import force_at, simulate_loading, simulate_series
from pointforce_ros.replica.contour import radius_by_angle
from pointforce_ros.replica.data import MeasuredPoke


def _time_residual(mesh, material, poke: MeasuredPoke, config):
    """Return ``(t (T,), residual (T,) N, holding (T,) bool)`` of ``poke``'s force-time record."""
    if poke.series is not None:
        t_sim, f_sim = simulate_series(mesh, material, poke, config)
        t_m, d_m, f_m = poke.series
        return t_m, np.interp(t_m, t_sim, f_sim) - f_m, d_m >= d_m.max() - 1e-12
    d, f = simulate_loading(mesh, material, poke, config, poke.speed)
    t_sim = np.arange(len(d)) * config.time_step
    t_sim = t_sim - t_sim[int(np.argmax(d >= 0))]
    t_meas = (poke.t - poke.t[0]) + poke.depth[0] / max(poke.speed, 1e-9)
    return t_meas, np.interp(t_meas, t_sim, f) - poke.force, np.zeros(len(t_meas), bool)


def residual_map(mesh, material, config, held: Sequence[MeasuredPoke],
                 section: Optional[Dict] = None) -> Dict:
    """Held-out residuals of a replica by depth, time, site and (optionally) section angle.

    Args:
        mesh, material, config: the replica.
        held: held-out pokes (thinned as the replica was scored).
        section: optional ``{'outline': (S, 2), 'centre': (2,), 'truth': (T, 2),
            'camera': (P, 2) or None}``: the replica's loaded section, its centre, the truth's
            section and the camera's section points, ``(x, z)`` metres.

    Returns:
        ``{'numbers': {...}, 'curves': {...}}``: JSON-able numbers (percent of each poke's
        peak force unless named ``_N``) and the arrays the figure draws.

    """
    depth_rows, time_rows, site_rows, curves = [], [], [], {'pokes': []}
    for p in held:
        peak = max(float(p.force.max()), 1e-9)
        pred = force_at(*simulate_loading(mesh, material, p, config), p.depth)
        resid = 100 * (pred - p.force) / peak
        frac = (p.depth - p.depth.min()) / max(float(np.ptp(p.depth)), 1e-12)
        thirds = [resid[(frac >= lo) & (frac <= lo + 1 / 3 + 1e-9)] for lo in (0, 1 / 3, 2 / 3)]
        depth_rows.append([float(np.mean(r)) if len(r) else float('nan') for r in thirds])
        deep = p.depth >= p.depth.max() - 0.02 * np.ptp(p.depth)
        at_max = 100 * float(np.mean(pred[deep]) - np.mean(p.force[deep])) / max(
            abs(float(np.mean(p.force[deep]))), 1e-9)
        t, r_t, holding = _time_residual(mesh, material, p, config)
        peak_t = max(float(np.max(p.series[2])) if p.series is not None else peak, 1e-9)
        if holding.any():
            parts = {'push': ~holding, 'hold': holding}
        else:
            half = t <= np.median(t)
            parts = {'first_half': half, 'second_half': ~half}
        row = {'poke': p.poke_id}
        for name, mask in parts.items():
            row[f'{name}_rms_pct'] = 100 * float(np.sqrt(np.mean(r_t[mask] ** 2))) / peak_t
            row[f'{name}_mean_pct'] = 100 * float(np.mean(r_t[mask])) / peak_t
        time_rows.append(row)
        site_rows.append({'poke': p.poke_id, 'x_m': float(p.xy[0]), 'y_m': float(p.xy[1]),
                          'depth_m': float(p.depth.max()), 'at_max_signed_pct': at_max,
                          'curve_rms_pct': float(np.sqrt(np.mean(resid ** 2)))})
        curves['pokes'].append({'poke': p.poke_id, 'depth': p.depth, 'resid_pct': resid,
                                't': t, 'resid_t_pct': 100 * r_t / peak_t,
                                'holding': holding, 'xy': p.xy, 'at_max_pct': at_max})
    depth_rows = np.array(depth_rows)
    numbers = {
        'by_depth': {'thirds': ['shallow', 'middle', 'deep'],
                     'mean_signed_pct': np.nanmedian(depth_rows, axis=0).tolist(),
                     'per_poke': depth_rows.tolist()},
        'by_time': {'pokes': time_rows,
                    'median': {k: float(np.median([r[k] for r in time_rows]))
                               for k in time_rows[0] if k != 'poke'}},
        'by_site': {'pokes': site_rows}}
    if section is not None:
        centre = np.asarray(section['centre'], float)
        ang = np.radians(np.arange(-180.0, 180.0, 1.0))
        rep = radius_by_angle(section['outline'], centre, ang)
        gap_truth = rep - radius_by_angle(section['truth'], centre, ang)
        width = float(np.ptp(np.asarray(section['truth'])[:, 0]))
        sectors = {}
        for lo in range(-180, 180, 30):
            m = (np.degrees(ang) >= lo) & (np.degrees(ang) < lo + 30)
            sectors[f'{lo}..{lo + 30}'] = 100 * float(np.mean(gap_truth[m])) / width
        numbers['by_section_angle'] = {
            'note': 'replica minus truth radius, mean per 30-degree sector about the deformed '
                    'centre, % of the truth width (0 deg: +x, 90: up)',
            'sectors_pct': sectors}
        curves['section'] = dict(section, angles=ang, gap_truth_pct=100 * gap_truth / width)
    return {'numbers': numbers, 'curves': curves}


def plot_residual_map(result: Dict, path, title: str = '') -> None:
    """Draw :func:`residual_map`'s result into the PNG ``path`` (2 x 2 panels)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    curves = result['curves']
    fig, ax = plt.subplots(2, 2, figsize=(11, 8.5))
    for c in curves['pokes']:
        ax[0, 0].plot(1e3 * c['depth'], c['resid_pct'], '.-', ms=3, label=c['poke'])
        line, = ax[0, 1].plot(c['t'], c['resid_t_pct'], lw=0.8, label=c['poke'])
        if np.any(c['holding']):
            t0 = c['t'][np.argmax(c['holding'])]
            ax[0, 1].axvline(t0, color=line.get_color(), lw=0.5, ls=':')
    ax[0, 0].axhline(0, color='k', lw=0.5)
    ax[0, 0].set(xlabel='depth past contact, mm', ylabel='replica - measured, % of peak',
                 title='held-out residual by depth')
    ax[0, 0].legend(fontsize=7)
    ax[0, 1].axhline(0, color='k', lw=0.5)
    ax[0, 1].set(xlabel='time from contact, s (dotted: hold starts)',
                 ylabel='replica - measured, % of peak', title='by time (force-time record)')
    if 'section' in curves:
        s = curves['section']
        ax[1, 0].plot(*np.asarray(s['truth']).T, 'k.', ms=3, label='truth (FEM)')
        ax[1, 0].plot(*np.asarray(s['outline']).T, 'r.', ms=3, label='replica')
        if s.get('camera') is not None:
            cam = np.asarray(s['camera'])
            ax[1, 0].plot(cam[:, 0], cam[:, 1], ',', color='tab:blue', alpha=0.5,
                          label='camera (rest-corrected)')
        ax[1, 0].set_aspect('equal')
        ax[1, 0].set(xlabel='x, m', ylabel='z, m', title='section under load (y = 0)')
        ax[1, 0].legend(fontsize=7)
        ax[1, 1].plot(np.degrees(s['angles']), s['gap_truth_pct'], 'r-')
        ax[1, 1].axhline(0, color='k', lw=0.5)
        ax[1, 1].set(xlabel='angle about the deformed centre, deg (0: +x, 90: up)',
                     ylabel='replica - truth radius, % of width', title='section residual '
                     'by position')
    else:
        if curves.get('surface') is not None:
            surf = np.asarray(curves['surface'])
            ax[1, 0].plot(1e3 * surf[:, 0], 1e3 * surf[:, 1], ',', color='0.8')
        xy = np.array([c['xy'] for c in curves['pokes']])
        val = np.array([c['at_max_pct'] for c in curves['pokes']])
        lim = max(float(np.max(np.abs(val))), 1e-6)
        sc = ax[1, 0].scatter(1e3 * xy[:, 0], 1e3 * xy[:, 1], c=val, cmap='coolwarm',
                              vmin=-lim, vmax=lim, s=80)
        for c in curves['pokes']:
            ax[1, 0].annotate(c['poke'][-3:], 1e3 * np.asarray(c['xy']), fontsize=7)
        fig.colorbar(sc, ax=ax[1, 0], label='signed error at the largest depth, %')
        ax[1, 0].set_aspect('equal')
        ax[1, 0].set(xlabel='x, mm', ylabel='y, mm', title='by site (held out)')
        thirds = np.array(result['numbers']['by_depth']['per_poke'])
        for row, c in zip(thirds, curves['pokes']):
            ax[1, 1].plot(['shallow', 'middle', 'deep'], row, 'o-', label=c['poke'])
        ax[1, 1].axhline(0, color='k', lw=0.5)
        ax[1, 1].set(ylabel='mean residual, % of peak', title='by depth third, per site')
        if len(curves['pokes']) <= 10:
            ax[1, 1].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
