"""Compiled kernels (NVIDIA Warp): one source for the CPU and CUDA.

``runtime`` initializes Warp once with a per-machine kernel cache and maps torch devices to
Warp devices; every other module here holds the kernels of one pipeline step. Kernels
replace numpy/torch code: the code they replaced lives on in ``tests/oracles/`` as the
reference they are tested against, never as a second runtime path.
"""
