"""Metrology: signed deviations, statistics, acceptance (area and region criteria), coverage."""
