"""Trajectory prediction with a smooth attention prior.

Holds the model, its settings and presets, the losses, training, evaluation, metrics and plots;
the dataset format, its readers and the torch dataset are the `trajectory_data` package's.
Importing this package imports nothing heavy.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__: str = version("smooth-attention")
except PackageNotFoundError:  # running from a checkout that was never installed
    __version__ = "0.0.0"

__all__ = ["__version__"]
