"""Geometry: pinhole cameras and the LR/HR rig (``camera``), SE(3) poses (``pose``), smooth
6-DoF B-spline trajectories (``trajectory``), the textured plane (``scene``) and the exact
motion field it induces (``motion``)."""
