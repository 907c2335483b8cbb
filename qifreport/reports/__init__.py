"""The human-readable reports: the one-page inspection PDF, the batch trend PDF, and the
offscreen deviation-map rendering they share."""
