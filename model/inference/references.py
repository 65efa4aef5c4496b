"""Images that carry no information about a recording, scored beside the methods.

They set the floor a method has to clear to have shown anything. ``flat`` is one grey at
the target's mean level (over the scored region under the ``observed`` normalisation):
what the affine fit makes of any featureless image. ``salt`` is that grey with a sparse
sprinkle of random dots (:data:`SALT_FRACTION` of the pixels, +-:data:`SALT_AMPLITUDE`),
seeded per frame so the rows repeat. Both are compared as they are (no normalisation: the
affine fit would scale uncorrelated dots away). Where a metric scores ``salt`` better than
``flat``, it rewards texture as such, not the recording's content.

The ceilings are the other end: the target itself inside the observed region
(:mod:`model.inference.observed`), knowing everything the events could show, and outside
it:

- ``seen+flat``: one grey at the mean the target has there (the true level of what no event
  saw); it draws nothing where no event fired, so a whole-frame score no better than it
  can only be beaten by drawing something there;
- ``seen+harmonic``: the smoothest continuation of the target from the region's rim (the
  fill of :func:`model.inference.fill.harmonic_fill` solved on the truth): the best an
  output that continues what it saw, without structure of its own, could do;
- ``seen+salt``: ``seen+flat`` with ``salt``'s random dots outside the region. It adds no
  information about the target, so where it scores better than ``seen+flat`` and
  ``seen+harmonic`` the metric rewards texture drawn where nothing was seen, not
  knowledge of it.

Scored over whole frames only (inside the region they are the target).
"""

from __future__ import annotations

import numpy as np

from model.inference.fill import harmonic_fill

REFERENCES = ("flat", "salt")
#: References that need the observed region and are scored over whole frames only.
CEILINGS = ("seen+flat", "seen+harmonic", "seen+salt")
SALT_FRACTION = 0.003
SALT_AMPLITUDE = 0.05


def reference_image(kind: str, target: np.ndarray, seed: int,
                    region: np.ndarray | None = None) -> np.ndarray:
    """float32 image of ``target``'s size in [0, 1]: the ``kind`` reference (module doc),
    its level the mean of ``target`` (over ``region`` when given; a ceiling's, outside
    ``region``); ``seed`` draws ``salt``'s dots."""
    if kind in CEILINGS:
        if region is None or region.all() or not region.any():
            raise ValueError(f"{kind} needs an observed region that is neither empty nor "
                             f"the whole frame")
        if kind == "seen+harmonic":
            return harmonic_fill(target, region).clip(0, 1).astype(np.float32)
        level = float(np.mean(target[~region]))
        outside = (reference_image("salt", np.full(target.shape, level, np.float32), seed)
                   if kind == "seen+salt" else level)
        return np.where(region, target, outside).astype(np.float32)
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
