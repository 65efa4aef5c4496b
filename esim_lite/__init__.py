"""esim_lite: an ESIM-style event camera simulator for planar scenes (library, no CLI).

Packages, each importing only from the ones before it:
``core`` (records shared by every stage: ``events``, ``frames``, ``stacking``, ``figures``,
``dataconf``, ``atomic``, ``scales``); ``geometry`` (``camera``, ``pose``, ``trajectory``,
``scene``, ``motion``); ``render`` (``renderer`` in front of ``mitsuba`` and ``homography``,
``antialias``); ``events`` (``thresholds``, ``kernel``, ``reference``, ``noise``,
``simulator``, ``sampling``, and ``torch_kernel``/``triton_kernel`` for GPUs).
At the top: ``config`` (the simulation settings) and ``sequence`` (one whole sequence).
"""

__version__ = "0.1.0"
