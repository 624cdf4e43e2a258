"""Handheld from Python: visual modeling with a hand-held camera.

    import handheld
    handheld.reconstruct("photos/", "ws", until="sparse", progress=print)
    model = handheld.Workspace("ws").sparse()
    model.rotations, model.translations, model.xyz   # numpy arrays, pycolmap's conventions

`reconstruct` runs the same stages and writes the same files as `handheld reconstruct`; a
workspace written by either is read by `Workspace`. Errors are `HandheldError` (options:
`OptionsError`) with the command line's message.
"""

import platform as _platform
import sys as _sys

try:
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
except ImportError as _e:  # a wheel for another Python, platform or architecture
    raise ImportError(
        f"handheld: its compiled module does not load in this Python ({_platform.python_implementation()} "
        f"{_platform.python_version()}, {_sys.platform} {_platform.machine()}): {_e}. The package needs CPython 3.9 or "
        "newer (abi3) on the platform its wheel was built for: install the wheel built for this machine, or build "
        "one here with `maturin build --release` in crates/python"
    ) from _e

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
