"""esim_lite: an ESIM-style event camera simulator for planar scenes (library, no CLI).

Modules: ``camera``, ``pose``, ``trajectory``, ``scene``, ``motion`` (geometry);
``render_homography``/``render_mitsuba`` behind ``renderer`` (images); ``thresholds``,
``event_kernel``, ``noise``, ``simulator``, ``sampling`` (events); ``sequence`` (a whole
sequence); ``events``/``frames`` (records); ``config``/``dataconf`` (settings).
"""

__version__ = "0.1.0"
