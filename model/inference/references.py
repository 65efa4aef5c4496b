"""Images that carry no information about a recording, scored beside the methods.

They set the floor a method has to clear to have shown anything. ``flat`` is one grey at
the target's mean level (over the scored region under the ``observed`` normalisation):
what the affine fit makes of any featureless image. ``salt`` is that grey with a sparse
sprinkle of random dots (:data:`SALT_FRACTION` of the pixels, +-:data:`SALT_AMPLITUDE`),
seeded per frame so the rows repeat. Both are compared as they are (no normalisation: the
affine fit would scale uncorrelated dots away). Where a metric scores ``salt`` better than
``flat``, it rewards texture as such, not the recording's content.
"""

from __future__ import annotations

import numpy as np

REFERENCES = ("flat", "salt")
SALT_FRACTION = 0.003
SALT_AMPLITUDE = 0.05


def reference_image(kind: str, target: np.ndarray, seed: int,
                    region: np.ndarray | None = None) -> np.ndarray:
    """float32 image of ``target``'s size in [0, 1]: the ``kind`` reference (module doc),
    its level the mean of ``target`` (over ``region`` when given)."""
    if kind not in REFERENCES:
        raise ValueError(f"unknown reference {kind!r}; expected one of {REFERENCES}")
    level = float(np.mean(target[region] if region is not None else target))
    img = np.full(target.shape, level, np.float32)
    if kind == "salt":
        rng = np.random.default_rng(seed)
        dots = rng.random(target.shape) < SALT_FRACTION
        img[dots] += SALT_AMPLITUDE * rng.choice(np.array([-1.0, 1.0], np.float32),
                                                 int(dots.sum()))
    return img.clip(0, 1)
