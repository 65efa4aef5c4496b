"""The super-resolution scales and the HR cameras' names: what the simulator's rig, the
shards, the network and every CLI agree on.

An HR camera of scale ``s`` sees the event camera's view with ``s`` times its pixels along
each axis (:class:`esim_lite.geometry.camera.CameraRig`); its frames are stored, read and
scored under the name :func:`hr_camera` gives.
"""

from __future__ import annotations

from collections.abc import Iterable

SCALES = (2, 4, 8)
"""Super-resolution factors: the HR cameras a rig can carry (datagen renders them), the
factors the network has projection kernels for, and the ``--scale`` choices of every CLI."""


def hr_camera(scale: int) -> str:
    """Name of the HR intensity camera ``scale`` times the event camera's resolution."""
    return f"hr_x{scale}"


def check_scales(scales: Iterable[int], what: str = "scale") -> tuple[int, ...]:
    """``scales`` as a tuple if every one is in :data:`SCALES`, else a ValueError."""
    out = tuple(scales)
    if not out or any(s not in SCALES for s in out):
        raise ValueError(f"{what} must be {', '.join(map(str, SCALES[:-1]))} or {SCALES[-1]} "
                         f"(or several of them); got {', '.join(map(str, out)) or 'none'}")
    return out
