"""Rigid bodies in large rotation: their inertia from the mesh, and Moreau-Jean on them (docs/theory.md s. 12)."""
