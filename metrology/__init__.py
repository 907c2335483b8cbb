"""Metrology (``qifreport.metrology``): signed deviations, tolerance zones from PMI,
statistics, acceptance (area and region criteria), coverage, added material, repeatability,
SPC, and :func:`.inspection.inspect`, one inspection end to end on arrays."""
