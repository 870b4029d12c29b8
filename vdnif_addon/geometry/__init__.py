"""Geometry: the object in rest space (mesh, materials, albedo), its voxel grid, the rules
every walk through the cells shares, surface attributes, and the captured record of a
deforming object. Below the kernels: nothing here traces a ray."""
