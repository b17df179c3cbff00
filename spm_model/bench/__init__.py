"""The benchmark: feature cache and extraction, protocols, scoring, metrics (pose, up to symmetry, surface) and
the report."""
