"""Images: the renderer interface and its factory (``renderer``), the Mitsuba 3 ray caster
(``mitsuba``), the exact homography reference (``homography``) and the texture prefilter
against aliasing (``antialias``)."""
