"""Pose estimators built into the benchmark (SPM beside the methods it is compared with)."""
