"""facesim: anatomy-based facial animation (Erkoç's single-layer mass-spring-damper face
with Waters/Zhang muscles), simulated with Numba and rendered offscreen.

    import facesim
    spec = facesim.load_spec("expressions/happy.yaml")
    animation = facesim.simulate(spec)          # positions (frames, n, 3)
    facesim.render(animation, "out/happy.mp4")  # or .gif, .npz, a directory of PNGs

The package is in layers (docs/architecture.md): ``facesim.physics`` (the skin, its
muscles and solvers), ``facesim.face`` (heads, meshes, photos), ``facesim.animation``
(specs and simulating them), ``facesim.renderer`` and ``facesim.export``, the command
line on top. The names here are loaded on first use, so that ``import facesim.physics``
loads the simulation alone.
"""

from importlib import import_module

from .config import VERSION as __version__
from .errors import FacesimError, InputError, SimulationError

#: The public API: each name and the module it lives in.
_API = {
    "load_spec": "animation.spec", "Spec": "animation.spec",
    "simulate": "animation.simulate", "Animation": "animation.simulate",
    "render": "export.output",
    "Model": "physics.model", "build_model": "physics.model", "Material": "physics.material",
    "State": "physics.layout", "Control": "physics.layout",
}

__all__ = ["FacesimError", "InputError", "SimulationError", "__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        return getattr(import_module(f".{_API[name]}", __name__), name)
    raise AttributeError(f"module 'facesim' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API))
