"""From a spec to an animation: the spec format and its checks (``spec``), timelines,
FACS action units and blends (``timeline``), simulating a spec into an ``Animation``
(``simulate``: every frame's positions, the jaw, the pose, the muscle forces if asked),
and facesim's action units compared with ICT's scanned shapes (``calibration``).
"""
