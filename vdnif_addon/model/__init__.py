"""The model: the segment encoder, the intersection network and its heads, the variants'
configurations, and the model file that carries a trained network and its scene metadata."""
