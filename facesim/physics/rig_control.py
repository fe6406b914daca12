"""Where the bones take the skin in a frame: the jaw turning about its hinge and the
eyelids closing (facesim.physics.rig), and where the muscles' ends are as the bones move.
``control`` makes a frame's controls from a row of activations, the bones placed.
"""

import math

import numpy as np
from numba import njit

from ..config import NUMBA_OPTIONS
from .layout import Control, ModelArrays
from .muscles import LINEAR
from .numerics import _frame_point


def control(model: ModelArrays, activation: np.ndarray) -> Control:
    """The controls of one activation row (copied: a solver writes the controls it blends
    into it), the bones placed by ``_rig_control``."""
    muscles = model.muscle_kind.shape[0]
    c = Control(np.array(activation, dtype=np.float64), model.rest_position.copy(),
                np.zeros(model.rest_position.shape[0]), np.empty((muscles, 3)), np.empty((muscles, 3)))
    _rig_control(model, c)
    return c


@njit(**NUMBA_OPTIONS)
def _rotate(px, py, pz, hx, hy, hz, ax, ay, az, angle):
    """Point P turned by ``angle`` about the axis through H with unit direction A
    (Rodrigues' formula)."""
    vx, vy, vz = px - hx, py - hy, pz - hz
    c, s = math.cos(angle), math.sin(angle)
    dot = (ax * vx + ay * vy + az * vz) * (1.0 - c)
    return (hx + vx * c + (ay * vz - az * vy) * s + ax * dot,
            hy + vy * c + (az * vx - ax * vz) * s + ay * dot,
            hz + vz * c + (ax * vy - ay * vx) * s + az * dot)


@njit(**NUMBA_OPTIONS)
def _rig_control(model, control):
    """Where the jaw and eyelids (facesim.physics.rig) take each vertex under the activations of
    ``control``: its rest position slid over the eyeball by the lid closure c and the
    levator's raise a (c Δ_close + a (1 - c) Δ_raise in cylindrical coordinates about the
    eye's horizontal axis), then turned about the jaw hinge by w θ and carried by w times
    the jaw's glide (Σ activation × ``jaw_glide``), into ``control.target``; the turn's w
    is the vertex's jaw weight changed by the lips' seal s, w + s Δw (``jaw_seal``), the
    glide's its weight alone (sealed lips glide with the jaw). The lips drawn to a side
    (``lip_shift_column``: a_left, a_right) turn about the vertical axis of the face's
    cylinder (``axis_x``, ``axis_z``, ``radius``) by (a_left ``lip_shift``[0] - a_right
    ``lip_shift``[1]) / R, after the jaw's turn. Each lip rolled in (``lip_roll_column``:
    the upper, the lower) turns about the horizontal axis through its pivot by its
    activation times the vertex's share times its angle (``lip_roll``,
    ``lip_roll_pivot``, ``lip_roll_angle``), before the jaw's turn.
    ``control.hold`` is the extra stiffness driving the lips and lid contours,
    drive * min(1, 10 a) for the activation a of their control (a lid's: the largest of its
    closure, its raise and its eye's gaze controls; the jaw's: the largest of its opening
    and glides): zero while the jaw and lids are at rest. The lids follow their eye's
    gaze: each gaze control g adds (1 - c) g Δ_look (``lid_look_delta``) to the lid's
    (Δx, Δφ, Δr), closed lids no longer following it.
    Then the muscles' ends, from where the bones hold them (``_muscle_geometry``)."""
    activation = control.activation
    theta = model.jaw_max * activation[model.jaw_column] if model.jaw_column >= 0 else 0.0
    gx = gy = gz = 0.0
    to_left = to_right = 0.0  # the lips to one side, turning about the face's vertical axis
    if model.lip_shift_column[0] >= 0:
        to_left, to_right = activation[model.lip_shift_column[0]], activation[model.lip_shift_column[1]]
    shifting = max(to_left, to_right)
    roll_upper = roll_lower = 0.0  # each lip rolled in about its own horizontal axis
    if model.lip_roll_column[0] >= 0:
        roll_upper, roll_lower = activation[model.lip_roll_column[0]], activation[model.lip_roll_column[1]]
    rolling = max(roll_upper, roll_lower)
    sealed = activation[model.jaw_seal_column] if model.jaw_seal_column >= 0 else 0.0
    gliding = 0.0
    for k in range(model.jaw_glide_column.shape[0]):
        if model.jaw_glide_column[k] >= 0:
            g = activation[model.jaw_glide_column[k]]
            gliding = max(gliding, g)
            gx += g * model.jaw_glide[k, 0]
            gy += g * model.jaw_glide[k, 1]
            gz += g * model.jaw_glide[k, 2]
    for i in range(model.rest_position.shape[0]):
        px, py, pz = model.rest_position[i, 0], model.rest_position[i, 1], model.rest_position[i, 2]
        column = model.drive_column[i]
        a = activation[model.lid_raise_column[i]] if model.lid_raise_column[i] >= 0 else 0.0
        lx = lphi = lr = looking = 0.0
        for g in range(model.lid_look_column.shape[1]):
            if model.lid_look_column[i, g] >= 0:
                look = activation[model.lid_look_column[i, g]]
                looking = max(looking, look)
                lx += look * model.lid_look_delta[i, g, 0]
                lphi += look * model.lid_look_delta[i, g, 1]
                lr += look * model.lid_look_delta[i, g, 2]
        driving = max(activation[column], a) if column >= 0 else 0.0
        if column >= 0 and column == model.jaw_column:
            driving = max(driving, gliding, shifting, rolling)
        elif column >= 0 and column == model.lid_column[i]:
            driving = max(driving, looking)
        control.hold[i] = model.drive * model.drive_weight[i] * min(1.0, 10.0 * driving)
        if model.lid_column[i] >= 0:
            c = activation[model.lid_column[i]]
            a *= 1.0 - c  # the levator lets go as the lid closes: a blink closes a raised lid
            lx, lphi, lr = lx * (1.0 - c), lphi * (1.0 - c), lr * (1.0 - c)  # and closed lids no longer follow the gaze
            if c != 0.0 or a != 0.0 or looking != 0.0:
                dy = py - model.lid_centre[i, 1]
                dz = pz - model.lid_centre[i, 2]
                phi = math.atan2(dy, dz) + c * model.lid_delta[i, 1] + a * model.lid_raise_delta[i, 1] + lphi
                r = math.sqrt(dy * dy + dz * dz) + c * model.lid_delta[i, 2] + a * model.lid_raise_delta[i, 2] + lr
                px += c * model.lid_delta[i, 0] + a * model.lid_raise_delta[i, 0] + lx
                py = model.lid_centre[i, 1] + r * math.sin(phi)
                pz = model.lid_centre[i, 2] + r * math.cos(phi)
        for k in range(2):
            turn = (roll_upper if k == 0 else roll_lower) * model.lip_roll[i, k] * model.lip_roll_angle[k]
            if turn != 0.0:
                o = model.lip_roll_pivot[k]
                px, py, pz = _rotate(px, py, pz, o[0], o[1], o[2], 1.0, 0.0, 0.0, turn)
        w = model.jaw_weight[i] + sealed * model.jaw_seal[i]
        if theta != 0.0 and w > 0.0:
            h, a = model.jaw_hinge, model.jaw_axis
            px, py, pz = _rotate(px, py, pz, h[0], h[1], h[2], a[0], a[1], a[2], w * theta)
        slide = to_left * model.lip_shift[i, 0] - to_right * model.lip_shift[i, 1]
        if slide != 0.0:
            px, py, pz = _rotate(px, py, pz, model.axis_x, 0.0, model.axis_z, 0.0, 1.0, 0.0, slide / model.radius)
        if gliding != 0.0:  # the seal keeps the lips from parting, not from gliding with the jaw
            g = model.jaw_weight[i]
            px, py, pz = px + g * gx, py + g * gy, pz + g * gz
        control.target[i, 0] = px
        control.target[i, 1] = py
        control.target[i, 2] = pz
    _muscle_geometry(model, control.target, control.origin, control.insertion_point)


@njit(**NUMBA_OPTIONS)
def _muscle_geometry(model, target, origin, insertion_point):
    """The muscles' ends in the frame they act in (eq. 3.21's projection, or 3D), from
    where the bones hold them (``target``): O is the mean of the muscle's centre vertices
    (a linear muscle's attachment), I its insertion (a sphincter has none; I = O)."""
    for m in range(model.muscle_kind.shape[0]):
        for d in range(3):
            origin[m, d] = 0.0
        count = model.muscle_centre_start[m + 1] - model.muscle_centre_start[m]
        for k in range(model.muscle_centre_start[m], model.muscle_centre_start[m + 1]):
            _frame_point(target, model.muscle_centre_index[k], model.axis_x, model.axis_z, model.radius,
                         model.uv_projection, insertion_point, m)
            for d in range(3):
                origin[m, d] += insertion_point[m, d] / count
        if model.muscle_kind[m] == LINEAR:
            _frame_point(target, model.muscle_insertion[m], model.axis_x, model.axis_z, model.radius,
                         model.uv_projection, insertion_point, m)
        else:
            for d in range(3):
                insertion_point[m, d] = origin[m, d]
