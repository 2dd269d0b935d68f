"""CIVIC: Continuous In-situ Validation of Industrial Control models."""

__version__ = "0.1.0"
