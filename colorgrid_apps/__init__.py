"""Applications built on the ColorGrid core: the ``colorgrid`` command line, evaluation, GIF/MP4
export, the 3D replay viewer and the released replay set.

The core (``colorgrid``) imports nothing from here. The trainer (``train``) and the play server
(``server``) add their commands and policies through package entry points (``pyproject.toml``).
"""
