"""Measuring matchers against ground truth: dataset readers, metrics and the eval runner."""
