"""The finite-element model: meshes, M, K, C and loads, eigenmodes, the reduced model."""
