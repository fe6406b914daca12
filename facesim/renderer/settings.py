"""What a render is asked for (:class:`RenderSettings`: size, camera, framing, look, lines,
antialiasing) and the constants of facesim's look: the background, the lights, the
lines' colours, the antialiasing's thresholds. Checked when made: a bad --size or
--camera is one line, before anything is drawn.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError

#: Tried in this order by ``--backend auto``. Mesa's software EGL (surfaceless) first: it
#: renders the same frames about twice as fast as OSMesa here (BENCHMARKS.md), and newer
#: Mesa releases drop OSMesa; OSMesa remains the fallback.
BACKENDS = ("egl", "osmesa")


_LIBRARIES = {"osmesa": "OSMesa", "egl": "EGL"}


CAMERAS = {"front": 0.0, "three-quarter": 35.0, "profile": 90.0}


#: What a head's frame holds: its face (the simulated skin, brow to chin: expressions are
#: read there), or the whole head and shoulders.
FRAMINGS = ("face", "head")


#: How a head looks: facesim's materials under a key and a fill light (clay), or a face
#: directory's baked photo (photo), drawn unlit: the photo's own light is in its colours.
LOOKS = ("auto", "clay", "photo")  # auto: photo for a head with a face directory, clay otherwise


#: In the photo look the parts a photo does not texture (teeth, gums and tongue) keep their
#: colours, shaded once at rest by the key light's direction (this much ambient, the rest
#: by the cosine to the light) and darkening with depth behind the front teeth, to the
#: second value at the third (cm): an open mouth is dark inside.
PHOTO_AMBIENT, MOUTH_DARKEST, MOUTH_DEEP = 0.45, 0.2, 3.5


BACKGROUND = (0.93, 0.93, 0.95, 1.0)


ARROW = (0.85, 0.05, 0.05, 1.0)


WIRE = (0.12, 0.14, 0.22, 1.0)


#: A head's wireframe is drawn this far (cm) in front of the skin, toward the camera.
WIRE_LIFT = 0.15


KEY_LIGHT, FILL_LIGHT = 3.2, 1.3


#: Where the key light comes from (up and to the subject's right, in front), and the fill.
KEY_DIRECTION, FILL_DIRECTION = np.array([-0.6, 0.7, 1.0]), np.array([0.9, -0.1, 0.6])


#: Antialiasing, by default, filters the frame as drawn along its edges (``_smooth_edges``):
#: a pixel whose 3x3 neighbourhood's luma spans at least ``EDGE_CONTRAST`` of its
#: brightest (and ``EDGE_FLOOR`` levels) is blended toward its neighbour across the edge.
#: ``supersample`` renders each frame this many times wider and taller and averages the
#: blocks instead (``_downsample``): 4 samples per pixel, twice the frame's cost, faster
#: than multisampling in software (108 ms a frame of the head at 512² with 2 or 4 samples,
#: 35 ms with one). Frames larger than ``SUPERSAMPLE_LIMIT`` are filtered; frames with
#: lines (their one-pixel lines would fade or smear) are drawn with 4 samples a pixel.
SUPERSAMPLE, SUPERSAMPLE_LIMIT = 2, 4096


EDGE_CONTRAST, EDGE_FLOOR = 0.125, 255.0 / 24.0


#: Height of the head's pivot (the atlanto-occipital joint) above the chin, in face heights.
NECK_HEIGHT = 0.25


@dataclass(frozen=True)
class RenderSettings:
    width: int = 512
    height: int = 512
    camera: str = "front"
    wireframe: bool = False
    show_muscles: bool = False
    antialias: bool = True
    framing: str = "face"
    look: str = "auto"
    onto: Path | None = None  # a photo to render into, through its face directory's fitted camera
    supersample: bool = False  # antialias by 4 samples per pixel, not by the edge filter

    def __post_init__(self):
        if not (16 <= self.width <= 8192 and 16 <= self.height <= 8192):
            raise InputError(f"--size: expected WxH between 16 and 8192, got {self.width}x{self.height}")
        if self.camera not in CAMERAS:
            raise InputError(f"--camera: expected one of {', '.join(CAMERAS)}, got {self.camera!r}")
        if self.framing not in FRAMINGS:
            raise InputError(f"--framing: expected one of {', '.join(FRAMINGS)}, got {self.framing!r}")
        if self.look not in LOOKS:
            raise InputError(f"--look: expected one of {', '.join(LOOKS)}, got {self.look!r}")

    def for_face(self, face) -> "RenderSettings":
        """These settings for a head with the face directory ``face`` (or None): the auto
        look made photo or clay; InputError when the photo look or --onto has no face."""
        if face is None and (self.look == "photo" or self.onto is not None):
            what = "--onto" if self.onto is not None else "--look photo"
            raise InputError(f"{what}: needs a face directory (--face DIR, or face: in the spec; "
                             "make one with `facesim face from-photo`)")
        return replace(self, look="clay" if face is None else "photo") if self.look == "auto" else self


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size: expected WxH such as 512x512, got {text!r}") from None
    return w, h
