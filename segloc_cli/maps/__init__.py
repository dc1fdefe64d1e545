"""Building segment maps: fusing the segments of many scans, and tracing walls in rasters."""
