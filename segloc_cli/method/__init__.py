"""The two-stage method and what serves it: one stage per module, compiled kernels,
the verdict, and localizing a scan, a window or a track. Imports neither io nor click."""
