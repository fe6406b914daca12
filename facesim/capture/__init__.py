"""Performance capture: a face video read into facesim's controls (``facesim capture``).

MediaPipe Face Mesh tracks the face (``tracking``); the head's pose, each eye's gaze and
ARKit's shapes are solved per frame against facesim's own landmark motion (``solver``),
a turned head's misreading measured on facesim's head and on the subject's (``subject``);
the performance is written as an ordinary spec that ``facesim render`` replays on any
face, as Live Link Face's CSV curves, and as a plot (``performance``).
"""

from .performance import capture

__all__ = ["capture"]
