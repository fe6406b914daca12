"""The tongue as a rigged part of the head's figure (facesim.face.figure), moved in the
mandible's frame by two controls (facesim.physics.muscles.TONGUE), each 0-1:

- ``tongue_out`` (the genioglossus; FACS's AU19 tongue show, ARKit's tongueOut): the body
  slides forward over the lower incisors, the part over them lifted and thinned to pass
  between the incisal edges, all that slides narrowed;
- ``tongue_up`` (the superior longitudinal muscle; speech's /l/ and /t/): the tip curls up
  and back toward the alveolar ridge.

The tongue is a muscular hydrostat: it keeps its volume, so it thins and narrows as it
lengthens. Its motion is a rig, not a simulation: it touches nothing the skin's physics
feels, and ICT has no scanned shape for it; tests/test_tongue.py holds it to anatomy (the
tip shown at least a centimetre past the lower incisors, nothing of it inside a tooth at
any opening of the jaw). Lengths in cm, in ICT's frame at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Protrusion (``tongue_out``, the genioglossus; cm, ICT's frame at rest, carried by the
#: mandible): in front of TONGUE_ROOT the body slides forward, by up to TONGUE_REACH at the
#: tip. To pass over the lower incisors' edge (y -3.41) and under the upper's, what comes
#: over the incisors (from z LIFT_FROM to LIFT_AT, the lower incisors' lingual face) has
#: its midline lifted TONGUE_LIFT and thins to TONGUE_THIN of its thickness (1.4 cm there
#: at rest); all that slides narrows to TONGUE_NARROW of its width, as a muscular
#: hydrostat lengthening does, its sides passing inside the lower molars. The first
#: LIFT_PHASE of the control lifts the front in place; the rest slides.
TONGUE_ROOT, TONGUE_REACH = 6.0, 3.0
LIFT_FROM, LIFT_AT, TONGUE_LIFT, TONGUE_THIN, TONGUE_NARROW, LIFT_PHASE = 8.0, 9.4, 1.0, 0.6, 0.75, 0.25
#: The tongue passes between the incisors only once they are apart: its protrusion grows
#: from nothing at a jaw angle of OPEN_FROM to all of it at OPEN_AT (degrees; the incisal
#: edges are then 1.3 cm apart, the thinned tongue 0.85 cm thick). Closer, it stays behind them.
OPEN_FROM, OPEN_AT = 6.0, 10.0
#: The tip raised (``tongue_up``, the superior longitudinal muscle: /l/, /t/): in front of
#: TIP_FROM, by up to TIP_RAISE up and TIP_BACK back at the tip (toward the alveolar
#: ridge, behind the upper incisors), by the square of the way along; a protruded tongue
#: lies flat (the raise scaled by what is left of the protrusion).
TIP_FROM, TIP_RAISE, TIP_BACK = 7.5, 1.3, 0.3


def _smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True)
class Tongue:
    """The tongue's vertices (rows) at rest (in the mandible's frame), each one's way
    from the root to the tip for protrusion (``along``, 0-1: 0 behind TONGUE_ROOT) and for
    the tip's raise (``curl``, 0-1: 0 behind TIP_FROM), and the height of the tongue's
    midline where it lies (``midline``), about which it thins."""

    rows: np.ndarray
    rest: np.ndarray
    along: np.ndarray
    curl: np.ndarray
    midline: np.ndarray

    def displaced(self, out: float, up: float, jaw_angle: float) -> np.ndarray:
        """(k, 3) the rows' displacement in the mandible's frame for the controls ``out``
        and ``up`` (0-1) with the jaw turned ``jaw_angle`` (radians): the protrusion
        held back while the incisors are too close for the tongue to pass."""
        out = out * float(_smoothstep((np.degrees(jaw_angle) - OPEN_FROM) / (OPEN_AT - OPEN_FROM)))
        lift = float(_smoothstep(out / LIFT_PHASE))
        slide = max(out - LIFT_PHASE, 0.0) / (1.0 - LIFT_PHASE)
        d = np.zeros_like(self.rest)
        d[:, 2] = slide * TONGUE_REACH * self.along
        over = lift * _smoothstep((self.rest[:, 2] + d[:, 2] - LIFT_FROM) / (LIFT_AT - LIFT_FROM))
        d[:, 1] = over * (TONGUE_LIFT + (TONGUE_THIN - 1.0) * (self.rest[:, 1] - self.midline))
        # narrowing from the root on (its sides pass inside the lower molars as it slides)
        d[:, 0] = out * _smoothstep(3.0 * self.along) * (TONGUE_NARROW - 1.0) * self.rest[:, 0]
        tip = up * (1.0 - out) * self.curl ** 2
        d[:, 1] += TIP_RAISE * tip
        d[:, 2] -= TIP_BACK * tip
        return d


def tongue_rig(x: np.ndarray, rows: np.ndarray) -> Tongue:
    """The rig of the tongue whose vertices are ``rows`` of a head at rest ``x``."""
    rest = x[rows]
    tip = rest[:, 2].max()
    # the midline: halfway between the tongue's top and bottom, in 2.5 mm slices along it
    edges = np.arange(rest[:, 2].min(), tip + 0.25, 0.25)
    slice_ = np.clip(np.digitize(rest[:, 2], edges) - 1, 0, len(edges) - 1)
    middle = np.array([(rest[slice_ == k, 1].max() + rest[slice_ == k, 1].min()) / 2 if np.any(slice_ == k) else np.nan
                       for k in range(len(edges))])
    known = ~np.isnan(middle)
    midline = np.interp(rest[:, 2], edges[known] + 0.125, middle[known])
    return Tongue(rows, rest, np.clip((rest[:, 2] - TONGUE_ROOT) / (tip - TONGUE_ROOT), 0.0, 1.0),
                  np.clip((rest[:, 2] - TIP_FROM) / (tip - TIP_FROM), 0.0, 1.0), midline)
