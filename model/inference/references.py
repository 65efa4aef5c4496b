"""Images that carry no information about a recording, scored beside the methods.

They set the floor a method has to clear to have shown anything. ``flat`` is one grey at
the target's mean level (over the scored region under the ``observed`` normalisation):
what the affine fit makes of any featureless image. ``salt`` is that grey with a sparse
sprinkle of random dots (:data:`SALT_FRACTION` of the pixels, +-:data:`SALT_AMPLITUDE`),
seeded per frame so the rows repeat. Both are compared as they are (no normalisation: the
affine fit would scale uncorrelated dots away). Where a metric scores ``salt`` better than
``flat``, it rewards texture as such, not the recording's content.

``seen+flat`` is the other end, a ceiling: the target itself inside the observed region
(:mod:`model.inference.observed`), one grey outside it at the mean the target has there.
It knows everything the events could show and more (the true level of what they did not),
and draws nothing where no event fired; a whole-frame score no better than it can only be
beaten by drawing something there. Scored over whole frames only (inside the region it is
the target).
"""

from __future__ import annotations

import numpy as np

REFERENCES = ("flat", "salt")
#: References that need the observed region and are scored over whole frames only.
CEILINGS = ("seen+flat",)
SALT_FRACTION = 0.003
SALT_AMPLITUDE = 0.05


def reference_image(kind: str, target: np.ndarray, seed: int,
                    region: np.ndarray | None = None) -> np.ndarray:
    """float32 image of ``target``'s size in [0, 1]: the ``kind`` reference (module doc),
    its level the mean of ``target`` (over ``region`` when given)."""
    if kind in CEILINGS:
        if region is None or region.all() or not region.any():
            raise ValueError(f"{kind} needs an observed region that is neither empty nor "
                             f"the whole frame")
        return np.where(region, target, float(np.mean(target[~region]))).astype(np.float32)
    if kind not in REFERENCES:
        raise ValueError(f"unknown reference {kind!r}; expected one of "
                         f"{REFERENCES + CEILINGS}")
    level = float(np.mean(target[region] if region is not None else target))
    img = np.full(target.shape, level, np.float32)
    if kind == "salt":
        rng = np.random.default_rng(seed)
        dots = rng.random(target.shape) < SALT_FRACTION
        img[dots] += SALT_AMPLITUDE * rng.choice(np.array([-1.0, 1.0], np.float32),
                                                 int(dots.sum()))
    return img.clip(0, 1)
