"""A run told as plain functions: logs in, rows out, files written; a sweep on Dask;
the run file; the warm-up. No printing and no options."""
