"""Third-party datasets fetched by name, every file checked against its SHA-256.

>>> from slmlab import datasets
>>> datasets.names()[:3]
['pivchallenge-case-e', 'dice-calb-sys2', 'opencv-stereo-chessboard']
>>> folder = datasets.fetch("pivchallenge-case-e")      # doctest: +SKIP
>>> sorted(p.name for p in (folder / "Camera_01").glob("*.xml"))[:2]   # doctest: +SKIP
['img_0.xml', 'img_1.xml']

On the command line: ``python -m slmlab data list`` and ``python -m slmlab data fetch [NAME ...]``.
Where the files come from and where they go: :mod:`slmlab.datasets.cache`; what they are:
:mod:`slmlab.datasets.registry`; how each becomes a calibration set: :mod:`slmlab.datasets.converters`.
"""

from .cache import ENV_CACHE, ENV_MIRROR, ENV_URL, available, cache_dir, fetch, mirror_dir, server_url, status
from .registry import DataFile, Dataset, dataset, names

__all__ = ["fetch", "available", "status", "names", "dataset", "Dataset", "DataFile", "cache_dir", "mirror_dir",
           "server_url", "ENV_CACHE", "ENV_MIRROR", "ENV_URL"]
