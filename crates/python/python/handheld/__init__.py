"""Handheld from Python: visual modeling with a hand-held camera.

    import handheld
    handheld.reconstruct("photos/", "ws", until="sparse", progress=print)
    model = handheld.Workspace("ws").sparse()
    model.rotations, model.translations, model.xyz   # numpy arrays, pycolmap's conventions

`reconstruct` runs the same stages and writes the same files as `handheld reconstruct`; a
workspace written by either is read by `Workspace`. Errors are `HandheldError` (options:
`OptionsError`) with the command line's message.
"""

from ._handheld import (
    STAGES,
    HandheldError,
    OptionsError,
    SparseModel,
    Workspace,
    __version__,
    check_options,
    default_options,
    reconstruct,
)

__all__ = [
    "STAGES",
    "HandheldError",
    "OptionsError",
    "SparseModel",
    "Workspace",
    "__version__",
    "check_options",
    "default_options",
    "reconstruct",
]
