"""The observed region of a frame (where its events carry information) and metrics there.

Under a static camera a static background never fires, so nothing event-based can know it;
scoring the whole APS frame then measures how an image fills what no event saw. LPIPS
rewards texture of any kind there: on the DAVIS346 street clip a flat image sprinkled with
random dots scores a better whole-frame LPIPS than every reconstruction under the affine
fit (docs/benchmarks.md). The ``observed`` normalisation scores only where events fired:

- the region: pixels that fired during the output's stacks with at least
  :data:`MIN_NEIGHBOURS` other fired pixels among their 8 neighbours (the spatial half of
  the background-activity filter's rule: isolated noise events have no neighbours, edges
  do), dilated by :data:`RADIUS` pixels (a disc) to take in the sides of each edge, where
  a reconstruction decides what lies on either side;
- the prediction mapped by the least-squares scale and offset fitted inside the region;
- PSNR and MSE over the region's pixels, SSIM averaged over the windows centred in it,
  LPIPS's distance map (:meth:`model.losses.lpips.LPIPS.distance_map`) averaged over it;
- ``invented``: what the image draws where no event fired, the share of the pixels outside
  the region whose (fitted) value is more than :data:`INVENTED_STEP` away from the median
  of those pixels. 0 for a flat fill; an image that paints texture, clouds or blobs over a
  static background scores high.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from esim_lite.core.events import Events
from model.losses.lpips import LPIPS
from model.metrics.image import psnr_from_mse, ssim_map

#: Fired neighbours (of 8) a fired pixel needs to count as signal.
MIN_NEIGHBOURS = 2
#: Dilation of the supported pixels, in sensor pixels.
RADIUS = 5
#: Frames whose region covers fewer pixels than this are not scored under ``observed``.
MIN_PIXELS = 64
#: Distance from the unobserved pixels' median level (target intensity, after the fit) that
#: counts as drawn structure: 0.04, about 10 grey levels of 255.
INVENTED_STEP = 0.04


def support_mask(events: Events, radius: int = RADIUS,
                 min_neighbours: int = MIN_NEIGHBOURS) -> np.ndarray:
    """bool[H, W] at the sensor size of ``events``: the observed region (module doc)."""
    h, w = events.sensor_hw
    fired = np.zeros(h * w, bool)
    fired[events.y.astype(np.int64) * w + events.x.astype(np.int64)] = True
    return region_of(fired.reshape(h, w), radius, min_neighbours)


def region_of(fired: np.ndarray, radius: int, min_neighbours: int) -> np.ndarray:
    """bool[H, W]: the pixels of ``fired`` (bool[H, W]) with at least ``min_neighbours``
    fired among their 8 neighbours (0: all of them), dilated by a disc of ``radius``."""
    f = np.asarray(fired, bool).astype(np.float32)
    neighbours = cv2.boxFilter(f, -1, (3, 3), normalize=False,
                               borderType=cv2.BORDER_CONSTANT) - f
    supported = ((f > 0) & (neighbours >= min_neighbours - 0.5)).astype(np.uint8)
    if radius > 0:
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        supported = cv2.dilate(supported, disc)
    return supported.astype(bool)


def upscale_mask(mask: np.ndarray, scale: int) -> np.ndarray:
    """The region at ``scale`` times the size (each pixel becomes a scale x scale block);
    ``mask`` itself at scale 1."""
    return mask if scale == 1 else np.repeat(np.repeat(mask, scale, 0), scale, 1)


def affine_in(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``pred`` mapped by the least-squares scale and offset to ``gt`` over ``mask``,
    clipped to [0, 1] (the whole image is mapped)."""
    p, g = pred[mask].astype(np.float64), gt[mask].astype(np.float64)
    a = np.stack([p, np.ones_like(p)], 1)
    coef, *_ = np.linalg.lstsq(a, g, rcond=None)
    return (coef[0] * pred + coef[1]).clip(0, 1).astype(np.float32)


def masked_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray,
                   lpips_net: LPIPS | None) -> dict | None:
    """Metrics of ``pred`` (already mapped) against ``gt`` inside ``mask``; None when the
    region is smaller than :data:`MIN_PIXELS` pixels."""
    if pred.shape != gt.shape or mask.shape != gt.shape:
        raise ValueError(f"prediction {pred.shape}, target {gt.shape} and region "
                         f"{mask.shape} differ in size")
    if int(mask.sum()) < MIN_PIXELS:
        return None
    err = float(np.mean((pred[mask].astype(np.float64) - gt[mask]) ** 2))
    p, g = torch.from_numpy(pred)[None, None], torch.from_numpy(gt)[None, None]
    out = {"psnr": psnr_from_mse(err), "mse": err, "coverage": float(mask.mean())}
    inner = mask[5:-5, 5:-5]  # SSIM's map entry [i, j] is the window centred on (i+5, j+5)
    smap = ssim_map(p, g)[0, 0].numpy()
    out["ssim"] = float(smap[inner].mean()) if inner.any() else float("nan")
    if lpips_net is not None and min(pred.shape) >= 32:
        with torch.inference_mode():
            dmap = lpips_net.distance_map(p, g)[0, 0].numpy()
        out["lpips"] = float(dmap[mask].mean())
    if int((~mask).sum()) >= MIN_PIXELS:
        out["invented"] = invented_share(pred, mask)
    return out


def invented_share(pred: np.ndarray, mask: np.ndarray) -> float:
    """Share of the pixels outside ``mask`` more than :data:`INVENTED_STEP` away from
    their median value (module doc)."""
    outside = pred[~mask].astype(np.float64)
    return float(np.mean(np.abs(outside - np.median(outside)) > INVENTED_STEP))
