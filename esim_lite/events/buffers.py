"""Typed event buffers on a torch device, shared by the torch and Triton event kernels.

torch is imported only here and in those two kernels; the rest of ``esim_lite`` does not
need it.
"""

from __future__ import annotations

import torch

#: dtypes of an event list (x, y, t, p), as in :class:`esim_lite.core.events.Events`.
EVENT_DTYPES = (torch.int16, torch.int16, torch.int64, torch.int8)


def event_buffers(n: int, device: torch.device
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Uninitialised (x, y, t, p) tensors of length ``n`` (``n = 0``: no events)."""
    return tuple(torch.empty(n, dtype=dt, device=device) for dt in EVENT_DTYPES)
