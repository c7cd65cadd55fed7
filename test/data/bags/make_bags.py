"""Regenerate ``test/data/bags/pokes/``: a small poke store for the replay tests.

Scenario: the simulated cell's analytic stand-in object (flat top at z = 0.04 m with a stiffness
ripple, k0 = 1.4e4 N/m^1.5, ripple 0.3), scenario ``realistic`` (camera bias 2 mm, F/T noise),
4 point pokes at seeded random locations, 5 mm/s, 3 N force limit, 250 Hz. Same seed, same bytes
of the arrays (the MCAP container also stores write times, so files may differ byte-wise).

Usage: python test/data/bags/make_bags.py
"""

import shutil
from pathlib import Path

from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.pokes.store import PokeStore

HERE = Path(__file__).resolve().parent
OBJECT = halfspace_object(HalfSpaceContact(z0=0.04, k0=1.4e4, ripple=0.3, wavelength=0.06),
                          region=((0.48, 0.52), (-0.02, 0.02)))


def records():
    """The four poke records of the fixture."""
    return simulate_campaign(OBJECT, load_scenario('realistic'), count=4, seed=11, speed=0.005,
                             standoff=0.005, force_limit=3.0, depth_limit=0.01, gap=0.5,
                             start_time=1000.0)


def main():
    """Write the store."""
    out = HERE / 'pokes'
    shutil.rmtree(out, ignore_errors=True)
    store = PokeStore(out)
    for record in records():
        store.add(record)
        print(f'{record.poke_id}: {len(record)} samples')


if __name__ == '__main__':
    main()
