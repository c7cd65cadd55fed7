"""pointforce_ros.contact: the semi-empirical contact simulator (seed 000, section IV)."""

from pointforce_ros.contact.identify import (dent_profile, identify_shape_constant,
                                             identify_shape_constant_from_probe,
                                             identify_shape_constant_from_probes, ShapeFit)
from pointforce_ros.contact.lcp import (lcp_residual, LcpSolution, shape_function, shape_matrix,
                                        solve_lcp, solve_lcp_batch, solve_lcp_paper)
from pointforce_ros.contact.sampling import sample_mesh_surface
from pointforce_ros.contact.simulator import (BatchContactResult, ContactResult,
                                              ContactSimulator, normalise_approach)

__all__ = ['BatchContactResult', 'ContactResult', 'ContactSimulator', 'LcpSolution',
           'ShapeFit', 'dent_profile', 'identify_shape_constant',
           'identify_shape_constant_from_probe', 'identify_shape_constant_from_probes',
           'lcp_residual', 'normalise_approach',
           'sample_mesh_surface', 'shape_function', 'shape_matrix', 'solve_lcp',
           'solve_lcp_batch', 'solve_lcp_paper']
