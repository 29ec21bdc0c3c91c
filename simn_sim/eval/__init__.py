"""Evaluation of estimated trajectories against ground truth."""
