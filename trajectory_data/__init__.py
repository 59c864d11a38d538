"""The dataset layer: the trajectory file format and its readers and writers (`format`,
`reader`; h5py and numpy only), sharded datasets (`shards`), the torch dataset the predictor
trains on (`torch_dataset`, the one module that needs torch) and importers of public data sets
(`importers`). The generator (pipeline) writes through it and the predictor reads through it;
it imports neither, nor the scenarios.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__: str = version("smooth-attention")
except PackageNotFoundError:  # running from a checkout that was never installed
    __version__ = "0.0.0"

__all__ = ["__version__"]
