"""Studies above the pipeline: the demo, the paper's experiments, the speed/accuracy
sweep, the side-by-side against classical baselines, the network benchmark and the
reports they write. Nothing in the core or blender/ imports them."""
