"""Which compiled kernels a simulation runs: the parallel ones for a large mesh, their
serial twins for a small one.

A kernel with ``prange`` loops is compiled with ``parallel=True`` (facesim.config):
Numba outlines each loop into a function the threading layer runs on every core, and
compiles it about a third slower than the same loops as plain ones (a cold render of
the head: 53 s serial against 70 s, measured on 2026-12-04). A mesh below
``PARALLEL_FROM`` vertices gains nothing from threads (facesim.config), so ``for_mesh``
hands it each kernel's *serial twin*: the same Python function compiled without
``parallel``, with its calls to other kernels that reach a parallel loop, by name or
through their modules (``springs._spring_forces``), going to those kernels' twins. A
twin is made when first asked for and compiled when first called, so a run of the head
compiles no parallel kernel and one of a 30,000-vertex face no twin; each is cached on
disk under its kernel's name with ``__serial`` after it. The link terms scatter by
fixed slices whatever runs them (facesim.physics.numerics), so a twin adds its forces
in the same order as its kernel; LLVM may still vectorise a loop differently in the two,
and their positions agree to rounding (tests/test_kernels.py), where the parallel
kernels give the same bits on one thread as on two.
"""

import functools
import types

from numba import njit
from numba.core.registry import CPUDispatcher

from ..config import NUMBA_OPTIONS, PARALLEL_FROM

_PACKAGE = __name__.partition(".")[0]
_twins: dict[CPUDispatcher, CPUDispatcher] = {}


def _ours(value) -> bool:
    return isinstance(value, CPUDispatcher) and value.py_func.__module__.partition(".")[0] == _PACKAGE


def _callees(kernel: CPUDispatcher):
    """The kernels ``kernel`` may call: the names its code reads, as its module's globals
    or as attributes of facesim modules it reads."""
    names, space = kernel.py_func.__code__.co_names, kernel.py_func.__globals__
    for name in names:
        value = space.get(name)
        if _ours(value):
            yield value
        elif isinstance(value, types.ModuleType) and value.__name__.partition(".")[0] == _PACKAGE:
            yield from (getattr(value, attribute) for attribute in names if _ours(getattr(value, attribute, None)))


@functools.cache
def parallel(kernel: CPUDispatcher) -> bool:
    """Whether ``kernel`` runs a parallel loop, itself or in a kernel it calls."""
    return bool(kernel.targetoptions.get("parallel")) or any(parallel(callee) for callee in _callees(kernel))


def serial(kernel: CPUDispatcher) -> CPUDispatcher:
    """``kernel`` compiled without parallel loops (the module docstring): itself when it
    has none."""
    if not parallel(kernel):
        return kernel
    if kernel not in _twins:
        function = kernel.py_func
        space = dict(function.__globals__)
        for name in function.__code__.co_names:
            value = space.get(name)
            if _ours(value):
                space[name] = serial(value)
            elif isinstance(value, types.ModuleType) and value.__name__.partition(".")[0] == _PACKAGE:
                space[name] = _serial_module(value, function.__code__.co_names)
        twin = types.FunctionType(function.__code__, space, function.__name__, function.__defaults__,
                                  function.__closure__)
        twin.__qualname__ = f"{function.__qualname__}__serial"
        twin.__module__, twin.__doc__ = function.__module__, function.__doc__
        options = {key: value for key, value in kernel.targetoptions.items() if key != "nopython"}
        _twins[kernel] = njit(**dict(options, parallel=False, cache=NUMBA_OPTIONS["cache"]))(twin)
    return _twins[kernel]


def _serial_module(module: types.ModuleType, names) -> types.ModuleType:
    """A stand-in for ``module`` whose kernels among ``names`` are their serial twins."""
    stand_in = types.ModuleType(module.__name__, module.__doc__)
    stand_in.__dict__.update(vars(module))
    for name in names:
        if _ours(getattr(module, name, None)):
            setattr(stand_in, name, serial(getattr(module, name)))
    return stand_in


def on_threads(vertices: int, threads: int | None = None) -> bool:
    """Whether a mesh of ``vertices`` runs the parallel kernels: when asked to run on a
    number of ``threads`` (one included: the parallel code on one thread), else from
    ``PARALLEL_FROM`` vertices up (facesim.config)."""
    return threads is not None or vertices >= PARALLEL_FROM


def for_mesh(kernel: CPUDispatcher, vertices: int, threads: int | None = None) -> CPUDispatcher:
    """The kernel a mesh of ``vertices`` runs (``on_threads``): ``kernel`` or its serial twin."""
    return kernel if on_threads(vertices, threads) else serial(kernel)


def variants(kernel: CPUDispatcher) -> tuple[CPUDispatcher, ...]:
    """``kernel`` and its serial twin if one was made in this process."""
    return (kernel,) + ((_twins[kernel],) if kernel in _twins else ())
