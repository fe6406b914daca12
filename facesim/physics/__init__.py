"""The simulation (thesis chapter 3): the single-layer skin as a mass-spring-damper mesh
pulled by anatomical muscles, with the jaw and eyelids as a rig, integrated by Numba
kernels. Arrays in, arrays out: this layer imports nothing of facesim but its base
(config, errors, cache, geometry), and no renderer, schema or command line.

- ``mesh``        the face mesh and its topology (edges, neighbours, boundary loops)
- ``material``    the mass-spring-damper parameters, scaled to a mesh's resolution
- ``muscles``     the muscles and bones resolved onto a mesh (``MuscleSet``)
- ``rig``         the jaw and eyelids as per-vertex arrays (``Rig``)
- ``model``       ``build_model``: the immutable ``Model`` every kernel reads
- ``layout``      what the kernels read and write: ``ModelArrays``, ``State``,
                  ``Control``, ``Forces``, ``Workspace``
- the force terms, one module each, one line each in ``solver._forces``:
  ``springs`` (eq. 3.6), ``repulsion`` (eq. 3.7), ``bending`` (Bergou et al. 2006),
  ``damping`` (eq. 3.10), ``tissue`` (the hypodermis and the rig's drive),
  ``muscle_forces`` (eq. 3.1-3.4, 3.21-3.25, the flood fill of section 3.3)
- ``rig_control`` where the bones take the skin and the muscles' ends in a frame
- ``contacts``    lips and lids kept apart after each step
- ``checks``      inverted triangles (thesis fig. 3.16)
- ``numerics``    what the terms share: finiteness, eq. 3.6's coefficient, K's links
- ``solver``      the thesis's quasi-implicit update (eq. 3.14-3.20) and the implicit step
- ``run``         a model run from rest under a table of activations

A term adds, at the predicted positions X* (eq. 3.14), its force F_i and, where its force
depends on X_i, the scalar stiffness K_i = Σ ∂F_i/∂X_i along the spring (the Σ g + Σ h of
eq. 3.19), and damping terms their C_i = -∂F_i/∂V_i; a solver turns these into new
velocities. A new term is a module here and one line in ``solver._forces``
(docs/architecture.md).
"""
