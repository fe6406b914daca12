"""The blendshape vocabulary face rigs share: Apple ARKit's 52 shapes (what Live Link
Face, MediaPipe's face blendshapes and most capture and export tools speak), with ICT
FaceKit's spellings of its 57 as aliases, each resolved to a FACS form facesim drives
through its muscles and bones (facesim.animation.timeline). A spec's ``arkit:`` weights
and timeline targets take these names; ``facesim shapes`` lists them.

A weight is a shape's, 0-1, as a capture gives it: unlike ``aus:`` intensities, which
are FACS scores, weights are not passed through FACS's co-occurrence rules (a captured
smile and frown already are what the face did). ARKit's one-sided shapes are the
subject's side (``mouthSmileLeft`` lifts the subject's left corner, the ``_L`` of ICT
and of FACS's ``AU12_L``).

The map follows ICT FaceKit's FACS table (its README): ``mouthShrugUpper`` is its AU10,
``mouthUpperUp`` its AU11, ``cheekSquint`` its AU6. ICT's ``cheekRaiser_L`` is a second
scan of the same unit and maps to AU6_L too; ICT splits ARKit's ``browInnerUp`` into its
two sides (``browInnerUp_L``: AU1_L). ARKit's ``tongueOut``, which ICT lacks, drives the
tongue's rig (facesim.face.tongue.Tongue).
"""

from __future__ import annotations

from ..physics.muscles import PUPIL

#: ARKit's 52 blendshapes, Apple's spelling, in the order of Live Link Face's CSV.
ARKIT_52 = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft", "eyeWideLeft",
    "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight", "eyeSquintRight",
    "eyeWideRight",
    "jawForward", "jawRight", "jawLeft", "jawOpen",
    "mouthClose", "mouthFunnel", "mouthPucker", "mouthRight", "mouthLeft", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthPressLeft", "mouthPressRight",
    "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight",
    "noseSneerLeft", "noseSneerRight",
    "tongueOut",
)

#: ARKit's shapes that are one FACS unit on both sides, or on one side (``_L``/``_R``
#: added from the name's Left/Right), by ICT's table.
_PAIRED = {
    "eyeBlink": "AU45", "eyeSquint": "AU7", "eyeWide": "AU5", "mouthSmile": "AU12", "mouthFrown": "AU15",
    "mouthDimple": "AU14", "mouthStretch": "AU20", "mouthPress": "AU24", "mouthLowerDown": "AU16",
    "mouthUpperUp": "AU11", "browDown": "AU4", "browOuterUp": "AU2", "cheekSquint": "AU6", "noseSneer": "AU9",
}
_WHOLE = {
    "jawForward": "AU29", "jawLeft": "AU30_L", "jawRight": "AU30_R", "jawOpen": "AU27", "mouthFunnel": "AU22",
    "mouthPucker": "AU18", "mouthShrugLower": "AU17", "mouthShrugUpper": "AU10", "browInnerUp": "AU1",
    # no FACS unit: the lips sealed over the open jaw, a control of the jaw's rig (facesim.physics.rig)
    "mouthClose": "lip_seal",
    "mouthLeft": "mouth_left", "mouthRight": "mouth_right",
    # FACS's AU28 (lip suck) rolls both; ARKit and ICT roll each lip alone
    "mouthRollUpper": "lip_roll_upper", "mouthRollLower": "lip_roll_lower",
    # the eyes: up and down are FACS's AU63/AU64 per eye; out is toward the eye's own side
    "eyeLookUpLeft": "AU63_L", "eyeLookDownLeft": "AU64_L", "eyeLookOutLeft": "AU61_L", "eyeLookInLeft": "AU62_L",
    "eyeLookUpRight": "AU63_R", "eyeLookDownRight": "AU64_R", "eyeLookOutRight": "AU62_R", "eyeLookInRight": "AU61_R",
    "cheekPuff": "AU34",
    # the tongue alone, as ARKit's shapes are captured apart from jawOpen (FACS's AU19
    # opens the jaw with it)
    "tongueOut": "tongue_out",
}

def _facs(name: str) -> str | None:
    for stem, unit in _PAIRED.items():
        for side, letter in (("Left", "L"), ("Right", "R")):
            if name == stem + side:
                return f"{unit}_{letter}"
    return _WHOLE.get(name)


#: ARKit name -> its FACS form (or, with none, the control it drives), for the shapes
#: facesim simulates.
ARKIT_FACS = {name: _facs(name) for name in ARKIT_52}

#: ICT FaceKit's 57 shape names -> the ARKit name or FACS form they stand for.
ICT_ALIASES = {
    **{f"{stem}_{letter}": f"{stem}{side}" for stem in list(_PAIRED) + [f"eyeLook{d}" for d in ("Down", "In", "Out", "Up")]
       for letter, side in (("L", "Left"), ("R", "Right"))},
    "browInnerUp_L": "AU1_L", "browInnerUp_R": "AU1_R",
    "cheekRaiser_L": "AU6_L", "cheekRaiser_R": "AU6_R",
    "cheekPuff_L": "AU34_L", "cheekPuff_R": "AU34_R",
    # ICT's, not ARKit's: each pupil's dilation, a control drawn by the renderer
    "PupilDilate_L": f"{PUPIL}_l", "PupilDilate_R": f"{PUPIL}_r",
    **{name: name for name in ("jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker",
                               "mouthLeft", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
                               "mouthShrugUpper")},
}

#: Every name a spec's ``arkit:`` takes.
SHAPE_NAMES = tuple(ARKIT_52) + tuple(n for n in ICT_ALIASES if n not in ARKIT_52)


def shape_facs(name: str) -> str:
    """The FACS form (``AU12_L``) an ARKit or ICT shape name stands for, or the control
    it drives where FACS has no unit for it (``lip_seal``); ValueError for an unknown
    name."""
    arkit = ICT_ALIASES.get(name, name)
    if arkit.startswith(("AU", PUPIL)):
        return arkit
    if arkit not in ARKIT_FACS:
        raise ValueError(f"{name!r} is not an ARKit or ICT FaceKit shape name (see `facesim shapes`)")
    return ARKIT_FACS[arkit]


def is_shape_name(name: str) -> bool:
    return name in ARKIT_52 or name in ICT_ALIASES
