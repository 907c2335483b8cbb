"""The human-readable reports: the one-page inspection PDF, the interactive HTML deviation
map, the batch trend PDF, and the deviation-map colours and rendering they share.

* :mod:`~qifreport.reports.pdf` -- the inspection report (``write_pdf``), laid out from its
  blocks: :mod:`~qifreport.reports.header`, :mod:`~qifreport.reports.maps`,
  :mod:`~qifreport.reports.stats`, :mod:`~qifreport.reports.tables`,
  :mod:`~qifreport.reports.registration` and :mod:`~qifreport.reports.notes`, over
  :mod:`~qifreport.reports.context`.
* :mod:`~qifreport.reports.html` -- the interactive deviation map (``write_html``, ``--html``):
  one self-contained page drawn by three.js (:mod:`~qifreport.reports.threejs`, from the
  installed trimesh) and the package's ``viewer.js``/``viewer.css``.
* :mod:`~qifreport.reports.trend` -- the batch trend report (``write_trend_pdf``), with
  :mod:`~qifreport.reports.charts` and :mod:`~qifreport.reports.failures`; its statistics are
  :mod:`qifreport.metrology.spc`.
* :mod:`~qifreport.reports.kit` -- the house style and drawing primitives both share.
* :mod:`~qifreport.reports.render` -- the offscreen rendering of the deviation map.
"""

__all__: list[str] = []
