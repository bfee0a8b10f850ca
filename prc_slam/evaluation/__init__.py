"""Evaluation: classification and trajectory metrics, scorers, the peers we measure against."""
