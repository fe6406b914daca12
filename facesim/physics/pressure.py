"""Air pressure in the mouth: not in the thesis. Puffing the cheeks (FACS AU34, ARKit's
cheekPuff) is air held in the closed mouth above the pressure outside, pushing on the
wall of the oral cavity, the skin of the cheeks and lips over it: a membrane under a
pressure difference p carries the force F = p ∫ n dA over its surface, n its outward
normal. The cavity's wall is the rig's ``pressure_weight`` per vertex and side
(facesim.physics.rig: the skin over the oral cavity around the mouth, each cheek its
side's), so one cheek can be puffed while the other's buccinator holds it (AU34_L).
The skin is only the front of the cavity's closed wall, whose whole push nets to zero:
what the air pushes across the face (sideways, up or down) it pushes back as hard on the
walls across from the skin, the teeth, the palate, the floor of the mouth and a held
cheek, which are the skull's. So the skin takes the air's push less its net across the
face: it bulges away from the face without the whole sheet sliding toward the puffed
side (ICT's cheekPuff_L moves the lips forward and a little toward the middle).
"""


from numba import njit

from ..config import NUMBA_OPTIONS


@njit(**NUMBA_OPTIONS)
def _share(weight, v, a_left, a_right):
    """Vertex v's share of the pressure: Σ_side activation × its weight on that side."""
    return a_left * weight[v, 0] + a_right * weight[v, 1]


@njit(**NUMBA_OPTIONS)
def _pressure_forces(model, xp, control, forces):
    """The pressure in the mouth on its wall: each triangle's area vector at the
    predicted positions, A n = ½ (X_j - X_i) × (X_k - X_i) (outward: the rig's
    ``pressure`` carries the sign of the mesh's winding), shared equally among its three
    corners, each taking p_c A n / 3 with p_c = pressure × Σ_side activation × weight of
    that corner (the force on a membrane, F = p ∫ n dA); then the net of those forces
    across the face (x and y) taken back from the wall's vertices in proportion to their
    share of the pressure (the walls across from the skin are bone: the module's note). A
    follower load: its derivative is not symmetric, and it adds no stiffness, so an
    implicit step takes it as it was at the step's start (it changes slowly: the cheeks
    move millimetres)."""
    left, right = model.pressure_column[0], model.pressure_column[1]
    if left < 0:
        return
    a_left, a_right = control.activation[left], control.activation[right]
    if a_left == 0.0 and a_right == 0.0:
        return
    faces, weight, force = model.faces, model.pressure_weight, forces.force
    share = 0.0
    for v in range(weight.shape[0]):
        share += _share(weight, v, a_left, a_right)
    if share == 0.0:  # a mesh with no mouth has no cavity
        return
    across_x = across_y = 0.0
    for t in range(faces.shape[0]):
        i, j, k = faces[t, 0], faces[t, 1], faces[t, 2]
        if weight[i, 0] + weight[i, 1] + weight[j, 0] + weight[j, 1] + weight[k, 0] + weight[k, 1] == 0.0:
            continue
        ux, uy, uz = xp[j, 0] - xp[i, 0], xp[j, 1] - xp[i, 1], xp[j, 2] - xp[i, 2]
        vx, vy, vz = xp[k, 0] - xp[i, 0], xp[k, 1] - xp[i, 1], xp[k, 2] - xp[i, 2]
        nx, ny, nz = 0.5 * (uy * vz - uz * vy), 0.5 * (uz * vx - ux * vz), 0.5 * (ux * vy - uy * vx)
        for c in range(3):
            corner = faces[t, c]
            p = model.pressure * _share(weight, corner, a_left, a_right) / 3.0
            force[corner, 0] += p * nx
            force[corner, 1] += p * ny
            force[corner, 2] += p * nz
            across_x += p * nx
            across_y += p * ny
    for v in range(weight.shape[0]):
        taken = _share(weight, v, a_left, a_right) / share
        force[v, 0] -= taken * across_x
        force[v, 1] -= taken * across_y
