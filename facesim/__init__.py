"""facesim: anatomy-based facial expression animation (Erkoç's single-layer
mass-spring-damper face with Waters/Zhang muscles), simulated with Numba and rendered
offscreen.

    import facesim
    spec = facesim.load_spec("expressions/happy.yaml")
    animation = facesim.simulate(spec)       # positions (frames, n, 3)
"""

from .errors import FacesimError, InputError, SimulationError
from .simulate import Animation, simulate
from .spec import Spec, load_spec

__all__ = ["Animation", "FacesimError", "InputError", "SimulationError", "Spec", "load_spec", "simulate"]
__version__ = "0.1.0"
