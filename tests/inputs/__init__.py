"""Builders of small inputs (sweeps, captures, recordings, clouds) shared by the test modules."""
