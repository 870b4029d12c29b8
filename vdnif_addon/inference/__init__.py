"""Inference: a trained model on a scene. The neural render (walk, network, passes), the
metrics against both references, the evaluation that gathers them, and the pass images."""
