"""Figures for reports, one module per topic; each function returns ``ReportFigure`` objects
(:mod:`rig.report`) and imports matplotlib only when a figure is drawn."""
