"""Analyses of data and of compiled models.

- ``linearize``: :class:`~bondc.statespace.StateSpace` -> ``Linearization``
  (A, B, C, D, eigenvalues, natural frequencies, damping ratios);
- ``friction``, ``motors``: fits and checks against measured data.

Each module is imported on its own (``from bondc.analysis import linearize``),
so using one does not load the others' dependencies.
"""
