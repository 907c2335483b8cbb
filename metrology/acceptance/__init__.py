"""Acceptance: the tolerance zones on the surface (bands), the area and region criteria,
coverage, the decision rules with their uncertainty, summary statistics, added material and
the repeatability of out-of-tolerance regions."""
