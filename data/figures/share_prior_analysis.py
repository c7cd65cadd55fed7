"""Scoring of share rules on ``share_prior.py``'s cache (see that script's docstring)."""

import numpy as np
from scipy.optimize import minimize
from scipy.special import gammaln
from scipy.stats import t as student_t

from pointforce_ros.contact.identify import small_sample_factor
from pointforce_ros.contact.uncertainty import Z90


def log_marginal(errors, nu0: float, s0: float) -> float:
    """Log density of one object's held-out errors under the scaled inverse chi-square prior."""
    e = np.asarray(errors, dtype=float)
    n = len(e)
    return float(gammaln((nu0 + n) / 2) - gammaln(nu0 / 2) - 0.5 * n * np.log(np.pi * nu0 * s0 ** 2)
                 - 0.5 * (nu0 + n) * np.log1p(np.sum(e ** 2) / (nu0 * s0 ** 2)))


def fit_prior(groups) -> tuple:
    """``(nu0, s0)`` maximising the summed log marginal of the groups' errors."""
    def cost(v):
        return -sum(log_marginal(g, np.exp(v[0]), np.exp(v[1])) for g in groups)
    rms = float(np.sqrt(np.mean(np.concatenate([np.square(g) for g in groups]))))
    best = min((minimize(cost, [np.log(nu), np.log(rms)], method='Nelder-Mead')
                for nu in (1.0, 4.0, 16.0)), key=lambda r: r.fun)
    nu0, s0 = np.exp(best.x)
    return float(min(nu0, 1e4)), float(s0)


def share(inner, in_sample: float, prior=None) -> float:
    """A rule's relative share from ``n`` inner errors: today's (``prior`` None) or shrunk."""
    e = np.asarray(inner, dtype=float)
    n = len(e)
    ms = float(np.mean(e ** 2)) if n else 0.0
    if prior is None:          # calibrate_shape's rule
        return max(np.sqrt(ms) * small_sample_factor(n) if n else 0.0, in_sample)
    nu0, s0 = prior
    s2 = (nu0 * s0 ** 2 + n * ms) / (nu0 + n)
    return max(np.sqrt(s2) * student_t.ppf(0.95, nu0 + n) / Z90, in_sample)


def z_normal(row, rel: float) -> tuple:
    """``(z, width)`` of each step of one cached trial under share ``rel``.

    ``z``: the error along the push over its standard deviation; ``width``: the 90 % interval
    of the force vector over the true force.
    """
    w = np.asarray(row['wrench'])
    std = np.sqrt(np.asarray(row['std0']) ** 2 + (rel * np.abs(w)) ** 2)[:, :3]
    a = np.asarray(row['approach'])
    err = (w[:, :3] - np.asarray(row['true_force'])) @ a
    return err / np.maximum(np.sqrt(np.sum((std * a) ** 2, axis=1)), 1e-12), \
        2 * Z90 * np.linalg.norm(std, axis=1) / np.maximum(np.linalg.norm(row['true_force'],
                                                                            axis=1), 1e-9)


def analyse(cache) -> None:
    names = list(cache)
    print('[share] per object: held-out errors of its trials (each from the others)')
    for name in names:
        print(f'  {name}: ' + ', '.join(f'{r["error"]:.0%}' for r in cache[name]))
    # label: (the inner errors used, the prior of an object or None)
    rules = {'today': ('inner', lambda name: None),
             'prior (loo objects)': ('inner', lambda name: fit_prior(
                 [[r['error'] for r in cache[o]] for o in names if o != name]))}
    if all('inner_full' in r for rows in cache.values() for r in rows):
        rules['full leave-one-out'] = ('inner_full', lambda name: None)
    for label, (key, prior_of) in rules.items():
        zs, widths = [], []
        print(f'[share] rule {label}')
        for name in names:
            prior = prior_of(name)
            zo, wo = [], []
            for row in cache[name]:
                rel = share(row[key], row['in_sample'], prior)
                z, w = z_normal(row, rel)
                zo.append(z)
                wo.append(w)
            zo, wo = np.concatenate(zo), np.concatenate(wo)
            zs.append(zo)
            widths.append(wo)
            extra = f' prior nu0 {prior[0]:.1f}, s0 {prior[1]:.0%};' if prior else ''
            print(f'  {name}:{extra} covered {np.mean(np.abs(zo) <= Z90):.0%} of {len(zo)}, '
                  f'median width {np.median(wo):.0%} of the force')
        z, w = np.concatenate(zs), np.concatenate(widths)
        print(f'  pooled: {np.mean(np.abs(z) <= Z90):.1%} of {len(z)} '
              f'({int(np.sum(np.abs(z) <= Z90))}), median width {np.median(w):.0%}')
    everything = fit_prior([[r['error'] for r in cache[o]] for o in names])
    no_lamb = fit_prior([[r['error'] for r in cache[o]] for o in names if o != 'lamb'])
    print(f'[share] prior on all objects: nu0 {everything[0]:.1f}, s0 {everything[1]:.1%}; '
          f'without lamb: nu0 {no_lamb[0]:.1f}, s0 {no_lamb[1]:.1%}')
