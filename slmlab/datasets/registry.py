"""The registry of third-party datasets: every file a notebook, test or benchmark reads, with its public URL
and SHA-256.

The registry is data, not code: ``registry.json`` beside this module (found from ``Path(__file__).parent``,
as pvlib finds its data). Each dataset is a folder of files laid out as in the original repository's
snapshot; each file carries

* ``path``: its place inside the dataset's folder (``/``-separated),
* ``size``: its length [bytes],
* ``sha256``: its SHA-256, checked every time the file is used,
* ``url``: the original public address, at a fixed commit of the repository it comes from.

Files the datasets' provenance calls *derived* (conversions written by hand, not upstream) are not in the
registry; code that needs such a table derives it from the upstream files (:mod:`slmlab.thirdparty`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from ..errors import SlmlabError

__all__ = ["REGISTRY_FILE", "DataFile", "Dataset", "names", "dataset"]

#: the registry (JSON), shipped inside the package; read (once per path) when first needed
REGISTRY_FILE = Path(__file__).parent / "registry.json"
_FORMAT = "slmlab-datasets/1"


@dataclass(frozen=True)
class DataFile:
    """One registered file: ``path`` inside the dataset's folder, ``size`` [bytes], ``sha256`` (hex) and the
    original ``url``."""

    path: str
    size: int
    sha256: str
    url: str


@dataclass(frozen=True)
class Dataset:
    """A named dataset: the ``folder`` its files live in (in the cache, a mirror or a server), a one-line
    ``title``, its ``licence``, the ``repository`` and ``commit`` it was taken from, and its ``files``."""

    name: str
    folder: str
    title: str
    licence: str
    repository: str
    commit: str
    files: tuple[DataFile, ...]

    @property
    def size_bytes(self) -> int:
        """The dataset's total size [bytes]."""
        return sum(f.size for f in self.files)


@lru_cache(maxsize=4)
def _read(path: Path) -> dict[str, Dataset]:
    raw = json.loads(path.read_text(encoding="utf-8"))
    if raw.get("format") != _FORMAT:
        raise SlmlabError(f"is not a dataset registry of format {_FORMAT}", path)
    out = {}
    for name, d in raw["datasets"].items():
        files = tuple(DataFile(f["path"], int(f["size"]), f["sha256"], f["url"]) for f in d["files"])
        out[name] = Dataset(name, d["folder"], d["title"], d["licence"], d["repository"], d["commit"], files)
    return out


def _registry() -> dict[str, Dataset]:
    return _read(REGISTRY_FILE)


def names() -> list[str]:
    """The registered datasets' names, in the registry's order."""
    return list(_registry())


def dataset(name: str) -> Dataset:
    """The registered dataset ``name``; an unknown name raises :class:`SlmlabError` listing the known ones."""
    reg = _registry()
    if name not in reg:
        raise SlmlabError(f"unknown dataset {name!r}; the datasets are {', '.join(reg)} "
                          "(see 'python -m slmlab data list')")
    return reg[name]
