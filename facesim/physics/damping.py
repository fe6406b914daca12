"""Viscous damping, eq. 3.10: its C_i = c per vertex, taken implicitly by the solvers.
"""


from numba import njit

from ..config import NUMBA_OPTIONS


@njit(**NUMBA_OPTIONS)
def _damping_forces(model, forces):
    """Viscous damping, eq. 3.10: F = -c V, left to the solver as C_i = c, which it takes
    at the new velocity (implicitly, as eq. 3.19 does)."""
    for i in range(forces.damping.shape[0]):
        forces.damping[i] += model.damping
