"""The judgement's stages, each a module with one public entry point and a typed output.

:func:`qifreport.metrology.judgement.judge` runs them in order on the seated scan
(:class:`~.context.Registered`) and the inspection's context (:class:`~.context.JudgeContext`);
a library user can run them one by one and look at each output:

1. :func:`.held.held_nominal` -- the nominal as the fixture holds it;
2. :func:`.deviation.deviation_stage` -- the points' and vertices' deviations, the free
   state's, the unscored bands;
3. :func:`.scoring.scoring_stage` -- the judged field, the scan points that judge it, the
   noise and the uncertainties;
4. :func:`.characteristics.characteristics_stage` -- the drawing's characteristics and the
   zones' datum frames;
5. :func:`.readings.located_readings` -- the deviations read in the located zones' frames;
6. :func:`.trim_edges.trim_edge_stage` -- the trim edges and the size (independent of 2-5:
   a caller may start it beside them);
7. :func:`.acceptance.acceptance_stage` -- area, region and coverage criteria on the whole
   part and on each zone; :func:`.detectable.detectable_stage` -- what each region criterion
   can see, and the regions it cannot tell from a failing one;
8. :func:`.added.added_stage` -- added material; :func:`.resolution.residual_scatter` -- the
   resolution.

The modules are layered in this order (pyproject's import-linter contract
``judgement-stages``): a stage imports only the earlier stages' outputs.
"""
