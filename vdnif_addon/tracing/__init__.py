"""Tracing: rays through the (deformed) cells and the exact answers along them. The training
rays, the deformed walk and the static grid walk, the ground-truth surface casts, and the two
references a model is measured against. Above the kernels, below the model."""
