"""Results as data: ``results/<study>/summary.json`` files and the tables rendered from them.

:mod:`mjxrmp.results.summary` writes a study's ``summary.json`` (command, device, versions, date,
tables) atomically; :mod:`mjxrmp.results.report` renders ``BENCHMARKS.md`` and the generated
tables inside ``docs/reports/<study>.md`` from those files (``scripts/report.py``).
"""
