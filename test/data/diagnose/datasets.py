"""Cell data sets for the diagnose tests: one per library effect, clean, two effects, foreign.

Every set pokes the analytic heterogeneous half-space (``HalfSpaceContact``, stiffness ripple
30 % over x, y) with the offline cell (:mod:`pointforce_ros.sim.session`): 16 pokes at
2-5 mm/s from a 2 mm stand-off to 4 N, 1 s hold, 100 Hz, F/T noise 2 mN (a good lab sensor at
100 Hz). Generation is fast (well under a second per set), so the tests build the sets on the
fly instead of committing arrays; run this file to write them as CSV tables for the CLI::

    python test/data/diagnose/datasets.py OUT_DIR

``TRUTH`` maps a set to the effect the cell applied and the parameter values diagnose must
recover (in the library's parameter names and units; for ``viscoelastic`` the total relaxing
fraction ``g`` of the library's fixed-time Prony series). ``below_resolution`` is noise-free with a
stiff table (20 N/mm): statistically detectable, but it moves the force by less than 0.1 % of
the force range, so diagnose must not add a term for it. ``stiff_arm`` is the same arm with
noise: the pokes cannot name it; probe trials measured through it
(``probe_trials.make_trials(..., compliance=STIFF_ARM)``) can.
"""

import sys
from pathlib import Path

import numpy as np

from pointforce_ros.sim import disturbances as ce
from pointforce_ros.sim.scenario import HalfSpaceContact, Scenario
from pointforce_ros.sim.session import simulate_campaign
from pointforce_ros.types import PokeRecord

NOISE = ce.FtNoise(force_std=0.002, torque_std=0.0001)
OBJECT = HalfSpaceContact(z0=0.04, k0=1.4e4, exponent=1.5, ripple=0.3, wavelength=0.05)
COMMON = dict(count=16, speed=(0.002, 0.005), standoff=0.002, force_limit=4.0, rate=100.0,
              hold=1.0, gap=2.0)

SETS = {
    'clean': ((), {}),
    'surface_offset': ((ce.CameraDepthBias(bias=0.0015),), {}),
    'ft_bias': ((ce.FtBias(force=(0.3, -0.2, 0.5)),), {'tare': False}),
    'ft_drift': ((ce.FtDrift(force_rate=(0.01, -0.008, 0.02)),), {}),
    'time_offset': ((ce.TimeOffset(offset=0.02),), {}),
    'viscoelastic': ((ce.ViscoelasticRelaxation(g=(0.2,), tau=(1.0,)),), {}),
    'hysteresis': ((ce.Hysteresis(eta=0.15, transition=0.0005),), {}),
    'series_compliance': ((ce.SeriesCompliance(stiffness=2000.0),), {}),
    'plastic_set': ((ce.PlasticSet(max_set=0.0008, n0=3.0, radius=0.004, min_force=1.0),),
                    {'count': 4, 'repeats': 4}),
    'friction': ((ce.Friction(mu=0.3),), {'normal_tilt_deg': (8.0, 20.0)}),
    'two_effects': ((ce.CameraDepthBias(bias=0.0015),
                     ce.ViscoelasticRelaxation(g=(0.2,), tau=(1.0,))), {}),
    'periodic': ((), {}),
    'below_resolution': ((ce.SeriesCompliance(stiffness=20000.0),), {'noise': False}),
    'stiff_arm': ((ce.SeriesCompliance(stiffness=20000.0),), {}),
}

TRUTH = {
    'surface_offset': {'surface_offset': {'offset': 0.0015}},
    'ft_bias': {'ft_bias': {'fx': 0.3, 'fy': -0.2, 'fz': 0.5}},
    'ft_drift': {'ft_drift': {'rx': 0.01, 'ry': -0.008, 'rz': 0.02}},
    'time_offset': {'time_offset': {'offset': 0.02}},
    'viscoelastic': {'viscoelastic': {'g': 0.2}},
    'hysteresis': {'hysteresis': {'eta': 0.15, 'transition': 0.0005}},
    'series_compliance': {'series_compliance': {'compliance': 1.0 / 2000.0}},
    'plastic_set': {'plastic_set': {'max_set': 0.0008, 'n0': 3.0}},
    'friction': {'friction': {'mu': 0.3}},
    'two_effects': {'surface_offset': {'offset': 0.0015},
                    'viscoelastic': {'g': 0.2}},
}

FULL_TRUTH = {'viscoelastic': {'g': 0.2, 'tau': 1.0}}
"""The cell's effect where ``TRUTH`` compares one derived value: the one-term Prony series as
an effects mapping (for corrections with the true effect)."""

STIFF_ARM = 1.0 / 20000.0
"""Series compliance of ``stiff_arm`` (20 N/mm), m/N."""

PERIODIC = (0.1, 0.8)
"""Foreign disturbance of the ``periodic`` set: amplitude (N, along z) and frequency (Hz)."""


def _add_periodic(records, amplitude, frequency):
    out = []
    for rec in records:
        wrench = np.array(rec.wrench)
        wrench[:, 2] += amplitude * np.sin(2 * np.pi * frequency * rec.t_controller)
        out.append(PokeRecord(poke_id=rec.poke_id, point=rec.point, normal=rec.normal, t=rec.t,
                              t_controller=rec.t_controller, tcp_pose=rec.tcp_pose,
                              wrench=wrench, speed=rec.speed, probe=rec.probe,
                              outcome=rec.outcome, meta=rec.meta))
    return out


def make(name: str, seed: int = 1):
    """Return the records of data set ``name`` (deterministic for a seed)."""
    effects, extra = SETS[name]
    extra = dict(extra)
    noise = (NOISE,) if extra.pop('noise', True) else ()
    scenario = Scenario(name, seed=17, effects=noise + tuple(effects))
    records = simulate_campaign(OBJECT, scenario, seed=seed, **{**COMMON, **extra})
    if name == 'periodic':
        records = _add_periodic(records, *PERIODIC)
    return records


if __name__ == '__main__':
    from pointforce_ros.pokes.table import write_poke_table
    out = Path(sys.argv[1] if len(sys.argv) > 1 else '.')
    for set_name in SETS:
        print(write_poke_table(make(set_name), out / f'{set_name}.csv'))
