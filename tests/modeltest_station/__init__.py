"""Stations for the model-based tests (tests/test_modeltest.py): hubs.toml files and their models."""
