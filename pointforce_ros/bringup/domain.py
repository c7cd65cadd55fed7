"""A DDS domain of a run's own, for the simulated cell's demo and the benchmarks.

``pointforce demo`` and ``pointforce bench ros`` start nodes under the product's names
(``/poke_server/poke``, ``/contact_wrench/contact_wrench``, ...). In the user's domain they would
meet a real cell's nodes or another run's: a demo's planner could send its goals to a real arm's
poke server, a learner record another run's pokes. (Two runs on one machine did: a benchmark's
poke campaign sent goals to a demo's poke server, which refused them as busy, and the demo
stopped.) So these runs use a domain of their own, on localhost only, unless told which.
"""

import os
from contextlib import contextmanager
from typing import Iterator, Optional

FIRST_PRIVATE_DOMAIN = 100
"""Private domains are drawn from 100-199 (by process id); 0 is everyone's default."""


def private_domain_id(pid: Optional[int] = None) -> int:
    """Return the domain id a run of process ``pid`` (this process) takes by default."""
    return FIRST_PRIVATE_DOMAIN + (os.getpid() if pid is None else int(pid)) % 100


@contextmanager
def private_domain(domain: Optional[int] = None) -> Iterator[int]:
    """Run the ROS contexts created inside (and child processes) in a domain of their own.

    Args:
        domain: the domain id to use (0-232); ``None`` picks :func:`private_domain_id` and
            keeps discovery on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).

    Yields:
        The domain id in use. The environment is restored on exit.

    Raises:
        ValueError: ``domain`` outside 0-232 (the ids Fast DDS maps to ports on Linux).

    """
    if domain is not None and not 0 <= int(domain) <= 232:
        raise ValueError(f'ROS domain {domain} is outside 0-232')
    chosen = private_domain_id() if domain is None else int(domain)
    saved = {key: os.environ.get(key) for key in ('ROS_DOMAIN_ID',
                                                  'ROS_AUTOMATIC_DISCOVERY_RANGE')}
    os.environ['ROS_DOMAIN_ID'] = str(chosen)
    if domain is None:
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    try:
        yield chosen
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
