"""The face's colours (RGBA, 0-1) in facesim's clay look: the skin, the lips, the mouth
and its socket, the teeth and gums, the hair of the lashes and brows, and the eye. The
figure (facesim.face.figure) colours a head's parts with them, the renderer a mask's
eyeballs and mouth cavity, and the photo's bake (facesim.face.bake) balances a photo's
skin against ``SKIN``.
"""

SKIN = (0.86, 0.66, 0.55, 1.0)
LIPS = (0.74, 0.43, 0.42, 1.0)
MOUTH = (0.22, 0.05, 0.06, 1.0)
MOUTH_SOCKET = (0.30, 0.08, 0.09, 1.0)
GUMS = (0.72, 0.36, 0.38, 1.0)
TEETH = (0.93, 0.91, 0.84, 1.0)
LASHES = (0.22, 0.16, 0.12, 1.0)
BROWS = LASHES  # the same hair
CARUNCLE = (0.78, 0.50, 0.48, 1.0)
SCLERA = (0.95, 0.94, 0.92, 1.0)
IRIS = (0.28, 0.42, 0.52, 1.0)
PUPIL = (0.03, 0.03, 0.03, 1.0)
