"""numba-jitted time loops, one module per model family.

DESIGN.md names a single ``_kernels.py``; it is a package here so that each family's
loops stay in a small module of their own (operators, Preisach, differential models,
effect blocks) and can be developed and benchmarked independently.
Kernels take C-contiguous float64 arrays, write into preallocated outputs and loop over
walkers with ``prange``; they never allocate per sample.
"""
