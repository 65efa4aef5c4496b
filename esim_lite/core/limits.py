"""The stated limits on what one input may make a command hold in memory, in one place.

Every reader checks a size it reads from a file (a config's values, a sensor size, an image
header, a count of events) against these before allocating for it, and refuses with a
``ValueError`` that names the file, the size and the limit (docs/configuration.md and
docs/datasets.md state them). They sit far above any real input: the largest event sensors
are 1280x960, an APS frame is a few megapixels, a dataset config a few hundred values.
"""

from __future__ import annotations

import os
from pathlib import Path

MAX_CONFIG_BYTES = 1 << 20
"""A YAML config file (or a ``--set`` value), bytes."""
MAX_CONFIG_NODES = 100_000
"""Values (mappings, lists, scalars) of a YAML config once its aliases are expanded."""
MAX_SENSOR_PIXELS = 1 << 24
"""Pixels of an event sensor, read from a file, given by ``--sensor-size`` or simulated
(4096x4096; every side also below 2^15, as event coordinates are int16)."""
MAX_SENSOR_SIDE = (1 << 15) - 1
MAX_RENDER_PIXELS = 1 << 26
"""Pixels of the largest simulated camera (the LR sensor times its largest HR scale
squared), e.g. 2048x2048 at x4."""
MAX_IMAGE_PIXELS = 1 << 26
"""Pixels of one decoded image (a texture, an APS frame), read from its header first."""
MAX_IMAGE_BYTES = 1 << 28
"""Bytes of one encoded image file (or archive member) read to decode it."""
MAX_FRAME_PIXELS = 1 << 28
"""Pixels of all the APS frames of one recording together (1 GiB as float32)."""
MAX_EVENTS_HELD = 20_000_000
"""Events a command holds in memory at once where it needs them all (``calibrate``);
everything else streams recordings in chunks."""


def check_sensor_hw(hw: tuple[int, int], source: str | Path, what: str = "sensor") -> None:
    """Refuse a sensor size that is no image shape or exceeds :data:`MAX_SENSOR_PIXELS`.

    Raises:
        ValueError: naming ``source``, the size (W x H) and the limit.
    """
    h, w = (int(v) for v in hw)
    if h < 1 or w < 1:
        raise ValueError(f"{source}: {what} size {w}x{h} is not an image shape")
    if h > MAX_SENSOR_SIDE or w > MAX_SENSOR_SIDE or h * w > MAX_SENSOR_PIXELS:
        raise ValueError(f"{source}: {what} size {w}x{h} is larger than e2sr handles (at "
                         f"most {MAX_SENSOR_PIXELS:,} pixels, {MAX_SENSOR_SIDE} a side)")


def check_image_pixels(hw: tuple[int, ...], source: str | Path,
                       limit: int = MAX_IMAGE_PIXELS) -> None:
    """Refuse an image (its header's or a dataset's shape) above ``limit`` pixels, before
    anything decodes it.

    Raises:
        ValueError: naming ``source``, the image size and the limit.
    """
    h, w = int(hw[0]), int(hw[1])
    if h * w > limit:
        raise ValueError(f"{source}: a {w}x{h} image is larger than e2sr decodes (at most "
                         f"{limit:,} pixels)")


def cap_workers(workers: int) -> int:
    """``workers`` capped at the machine's cores (more processes only add memory)."""
    return max(1, min(workers, os.cpu_count() or 1))
