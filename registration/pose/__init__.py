"""Pose search: seating the nominal on a scan from any placement (paper Section 5.1) by
curvature descriptors, candidate starts, basins and a scored point-to-point ICP."""
