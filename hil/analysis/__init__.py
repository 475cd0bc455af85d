"""Analysis: one definition of each figure, the statistics, the plots and the reports.

:mod:`hil.analysis.metrics` (success windows, trials to criterion, footfall spread: each figure
defined once), :mod:`hil.analysis.stats` (intervals, running success), :mod:`hil.analysis.figures`
(the paper's figures), :mod:`hil.analysis.report` (a sweep's report), :mod:`hil.analysis.animation`
(GIFs), :mod:`hil.analysis.buslog` (reading a bus log: what is valid, and where the damage starts),
:mod:`hil.analysis.replay` (a recorded bus log fed to the controller offline),
:mod:`hil.analysis.busload` (bus load), :mod:`hil.analysis.legacy_config` (old JSON configurations).

May import: ``controller``, ``protocol``, :mod:`hil.experiments` (its registry), numpy, cantools;
matplotlib inside the functions that plot.
"""
