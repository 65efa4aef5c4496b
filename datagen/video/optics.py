"""From a video frame to the paired cameras' images: the colour rule and the HR/LR rule.

Colour: a frame's values are linearised (the sRGB curve, unless the config says they are
linear already), then reduced to luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (the
sRGB/Rec.709 primaries; events respond to the log of linear light, so the weights apply
to linear values, not to gamma-encoded ones as Rec.601 luma does). 8-bit values are divided
by 255, 16-bit by 65535; float files are taken as they are.

Geometry: the frame is centre-cropped to the LR sensor's aspect ratio (the largest
centred window of that ratio, its offset rounded down), then area-resized
(``cv2.INTER_AREA``: each output pixel the area-weighted mean of the input pixels it
covers) to the finest HR size, ``sensor x S`` with ``S`` the largest scale. Every coarser
image is the block mean of the finest: ``hr_x{s}`` by ``S / s``, the interpolator's working
image by ``S / work_scale``, and LR by ``work_scale`` from the working image, so that LR is
the mean of each ``S x S`` block of the finest HR image, the rule the renderer's paired
cameras follow (a pixel integrates the light over its area) and the x2 and x4 frames of
one video agree (the x2 frame is the 2x2 block mean of the x4 one).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from esim_lite.core.scales import hr_camera

#: Luminance weights of linear B, G, R (OpenCV's channel order).
LUMA_BGR = np.array([0.0722, 0.7152, 0.2126], np.float32)


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """The sRGB decoding curve (IEC 61966-2-1) of values in [0, 1] (float32)."""
    v = np.asarray(values, np.float32)
    return np.where(v <= 0.04045, v / np.float32(12.92),
                    ((v + np.float32(0.055)) / np.float32(1.055)) ** np.float32(2.4)
                    ).astype(np.float32)


_LUT: dict[tuple[int, str], np.ndarray] = {}


def _lut(bits: int, colour: str) -> np.ndarray:
    """float32 linear value of every integer code of ``bits`` bits."""
    key = (bits, colour)
    if key not in _LUT:
        codes = np.arange(1 << bits, dtype=np.float32) / np.float32((1 << bits) - 1)
        _LUT[key] = srgb_to_linear(codes) if colour == "srgb" else codes
    return _LUT[key]


def linear_luminance(frame: np.ndarray, colour: str) -> np.ndarray:
    """float32[H, W] linear luminance of a decoded frame.

    Args:
        frame: uint8, uint16 or float [H, W], [H, W, 1], [H, W, 3] (BGR) or [H, W, 4]
            (BGRA; alpha ignored).
        colour: ``srgb`` (encoded values) or ``linear``.
    """
    if frame.dtype == np.uint8 or frame.dtype == np.uint16:
        lin = _lut(8 if frame.dtype == np.uint8 else 16, colour)[frame]
    else:
        lin = np.asarray(frame, np.float32)
        lin = srgb_to_linear(np.clip(lin, 0.0, 1.0)) if colour == "srgb" else lin
    if lin.ndim == 3:
        lin = lin[..., 0] if lin.shape[2] == 1 else lin[..., :3] @ LUMA_BGR
    return np.ascontiguousarray(lin, np.float32)


def crop_box(frame_hw: tuple[int, int], sensor_hw: tuple[int, int]
             ) -> tuple[int, int, int, int]:
    """``(y0, x0, h, w)``: the largest window of the sensor's aspect ratio centred in the
    frame (its size rounded to the nearest pixel, its offset down)."""
    fh, fw = frame_hw
    sh, sw = sensor_hw
    if fw * sh > fh * sw:  # wider than the sensor: crop the sides
        h, w = fh, min(fw, int(round(fh * sw / sh)))
    else:
        h, w = min(fh, int(round(fw * sh / sw))), fw
    return (fh - h) // 2, (fw - w) // 2, h, w


def check_frame_size(frame_hw: tuple[int, int], sensor_hw: tuple[int, int], scale: int,
                     source: str) -> None:
    """Refuse a frame whose crop is smaller than the finest HR image (no upscaling).

    Raises:
        ValueError: naming ``source``, its size, the crop and the HR size needed.
    """
    _, _, h, w = crop_box(frame_hw, sensor_hw)
    need_h, need_w = sensor_hw[0] * scale, sensor_hw[1] * scale
    if h < need_h or w < need_w:
        raise ValueError(f"{source}: frames of {frame_hw[1]}x{frame_hw[0]} give a "
                         f"{w}x{h} crop at the sensor's aspect ratio, smaller than the "
                         f"x{scale} HR size {need_w}x{need_h} (sensor "
                         f"{sensor_hw[1]}x{sensor_hw[0]}); frames are never upscaled: "
                         f"use a smaller --sensor-size or --scale")


def block_mean(image: np.ndarray, k: int) -> np.ndarray:
    """float32[H / k, W / k]: the mean of every ``k x k`` block (``k`` divides H and W)."""
    if k == 1:
        return image
    h, w = image.shape
    return image.reshape(h // k, k, w // k, k).mean(axis=(1, 3), dtype=np.float64
                                                    ).astype(np.float32)


@dataclass(frozen=True, eq=False)
class CameraImages:
    """One video frame seen by the paired cameras (float32 linear intensity).

    Attributes:
        images: ``lr`` [h, w] and ``hr_x{s}`` [s h, s w] for every scale.
        work: the interpolator's working image, ``work_scale`` times LR.
    """

    images: dict[str, np.ndarray]
    work: np.ndarray


def camera_images(frame: np.ndarray, sensor_hw: tuple[int, int], scales: tuple[int, ...],
                  work_scale: int, colour: str) -> CameraImages:
    """The paired cameras' images of one decoded frame (see the module doc for the rule);
    the frame must be at least the finest HR size once cropped (:func:`check_frame_size`)."""
    finest = max(scales)
    y0, x0, h, w = crop_box(frame.shape[:2], sensor_hw)
    lin = linear_luminance(frame[y0:y0 + h, x0:x0 + w], colour)
    size = (sensor_hw[1] * finest, sensor_hw[0] * finest)
    top = lin if (w, h) == size else cv2.resize(lin, size, interpolation=cv2.INTER_AREA)
    top = np.ascontiguousarray(top, np.float32)
    work = block_mean(top, finest // work_scale)
    images = {"lr": block_mean(work, work_scale)}
    for s in sorted(scales):
        images[hr_camera(s)] = block_mean(top, finest // s)
    return CameraImages(images, work)
