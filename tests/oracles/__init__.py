"""Reference implementations the product's kernels are tested against: the numpy/torch code
each kernel replaced, kept as it was (a plain module imported by tests, never by the product)."""
