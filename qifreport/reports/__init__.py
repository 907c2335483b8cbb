"""The human-readable reports: the one-page inspection PDF, the batch trend PDF, and the
offscreen deviation-map rendering they share.

* :mod:`~qifreport.reports.pdf` -- the inspection report (``write_pdf``), laid out from its
  blocks: :mod:`~qifreport.reports.header`, :mod:`~qifreport.reports.maps`,
  :mod:`~qifreport.reports.stats`, :mod:`~qifreport.reports.tables`,
  :mod:`~qifreport.reports.registration` and :mod:`~qifreport.reports.notes`, over
  :mod:`~qifreport.reports.context`.
* :mod:`~qifreport.reports.trend` -- the batch trend report (``write_trend_pdf``), with
  :mod:`~qifreport.reports.charts` and :mod:`~qifreport.reports.failures`; its statistics are
  :mod:`qifreport.metrology.spc`.
* :mod:`~qifreport.reports.kit` -- the house style and drawing primitives both share.
* :mod:`~qifreport.reports.render` -- the offscreen rendering of the deviation map.
"""

__all__: list[str] = []
