"""Ways out: an animation written as MP4, GIF, a PNG sequence or NPZ positions
(``output``, each written under a temporary name, checked, then renamed), and the
static pictures, the muscle map and the expression sheet (``plots``).
"""
