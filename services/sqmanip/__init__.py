"""SQManip: superquadric-based robot manipulation stack."""

__version__ = "0.1.0"
