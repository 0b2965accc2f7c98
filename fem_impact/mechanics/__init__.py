"""The mechanical system in matrix form and its energy, with nothing of meshes.

- ``system``: ``Operators``, the system ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d0`` the
  integrators step, and its Delassus matrix; ``fem/`` assembles it from a mesh (or from modes);
- ``energy``: the energy budget of a step and the watch that stops a run which blows up or
  creates energy.
"""
