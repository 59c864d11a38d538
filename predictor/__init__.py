"""Trajectory prediction with a smooth attention prior.

Holds the dataset format (`predictor.format`, h5py + numpy only), the torch dataset, the model,
losses, training and evaluation. Importing this package imports nothing heavy: `predictor.format`
stays usable without torch.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__: str = version("smooth-attention")
except PackageNotFoundError:  # running from a checkout that was never installed
    __version__ = "0.0.0"

__all__ = ["__version__"]
