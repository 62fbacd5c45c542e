"""Vision: the report's tip tracker (Algorithm 1), affine calibration, the synthetic camera, and tracking video files
into time-stamped CSV logs."""
