"""pointforce_ros.contact: the semi-empirical contact simulator (seed 000, section IV).

Identifying the shape constant from probe trials lives in :mod:`pointforce_ros.contact.identify`
and is not imported here: it needs ``scipy.optimize``, which the contact service (every user of
the simulator) does not.
"""

from pointforce_ros.contact.lcp import (lcp_residual, LcpSolution, shape_function, shape_matrix,
                                        solve_lcp, solve_lcp_batch, solve_lcp_paper)
from pointforce_ros.contact.sampling import sample_mesh_surface
from pointforce_ros.contact.simulator import (BatchContactResult, ContactResult,
                                              ContactSimulator, normalise_approach)

__all__ = ['BatchContactResult', 'ContactResult', 'ContactSimulator', 'LcpSolution',
           'lcp_residual', 'normalise_approach',
           'sample_mesh_surface', 'shape_function', 'shape_matrix', 'solve_lcp',
           'solve_lcp_batch', 'solve_lcp_paper']
