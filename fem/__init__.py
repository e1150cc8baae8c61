"""Finite-element side of mlsim: geometry of the rod array, tetrahedral meshing, materials.

Importing this package is cheap: heavy dependencies (pytetwild, manifold3d, meshio) are imported
by the submodules that need them.
"""
