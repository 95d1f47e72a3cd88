"""Fetching registered datasets into the user's cache, every file checked against its SHA-256 on every use.

:func:`fetch` returns the dataset's folder in the cache (``pooch.os_cache("slmlab")``, or ``$SLMLAB_DATA_DIR``),
laid out as the dataset's folder of the registry. A file missing from the cache, or whose SHA-256 differs
from the registry's, is (re)fetched from the first of these sources:

1. a local mirror, a folder holding the datasets' folders: ``$SLMLAB_DATA_MIRROR``, by default
   ``../shared/realdata`` beside the repository when that exists (set the variable empty to ignore it);
2. ``$SLMLAB_DATA_URL``: a server holding the datasets' folders (``BASE/<folder>/<path>``);
3. the file's original URL in the registry.

pooch writes each file to a temporary name in the cache and renames it only once its SHA-256 matches, so a
failed download or a mismatch leaves nothing half-written behind; a mirror's file is copied the same way.
A failure raises :class:`slmlab.SlmlabError` with one line naming the file, where it was fetched from and
the remedy.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
from contextlib import contextmanager
from pathlib import Path

import pandas as pd
import pooch

from ..errors import SlmlabError
from .registry import DataFile, Dataset, dataset, names

__all__ = ["ENV_CACHE", "ENV_MIRROR", "ENV_URL", "cache_dir", "mirror_dir", "server_url", "file_source", "fetch",
           "available", "status"]

ENV_CACHE = "SLMLAB_DATA_DIR"
ENV_MIRROR = "SLMLAB_DATA_MIRROR"
ENV_URL = "SLMLAB_DATA_URL"
#: the default local mirror: ``../shared/realdata`` beside the repository (a source checkout)
_DEFAULT_MIRROR = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


def cache_dir() -> Path:
    """The folder the datasets' folders are cached in: ``$SLMLAB_DATA_DIR``, else pooch's per-user cache
    for ``slmlab`` (e.g. ``~/.cache/slmlab`` on Linux)."""
    d = os.environ.get(ENV_CACHE)
    return Path(d).expanduser() if d else Path(pooch.os_cache("slmlab"))


def mirror_dir() -> Path | None:
    """The local mirror in use, if any: ``$SLMLAB_DATA_MIRROR`` (empty: none), else ``../shared/realdata``
    beside the repository; ``None`` when that folder does not exist."""
    d = os.environ.get(ENV_MIRROR)
    path = _DEFAULT_MIRROR if d is None else (Path(d).expanduser() if d else None)
    return path if path is not None and path.is_dir() else None


def server_url() -> str | None:
    """``$SLMLAB_DATA_URL`` without a trailing ``/``, or ``None``."""
    url = os.environ.get(ENV_URL, "").strip().rstrip("/")
    return url or None


def file_source(ds: Dataset, f: DataFile) -> tuple[str, Path | None]:
    """Where ``f`` would be fetched from now: ``(address, mirror file or None)``; the address is the mirror
    file's path, ``$SLMLAB_DATA_URL/<folder>/<path>`` or the original URL."""
    mirror = mirror_dir()
    if mirror is not None and (mirror / ds.folder / f.path).is_file():
        local = mirror / ds.folder / f.path
        return str(local), local
    base = server_url()
    return (f"{base}/{ds.folder}/{f.path}" if base else f.url), None


def _copy_from(src: Path):
    """A pooch downloader that copies a mirror's file (pooch then checks it and renames it into place)."""
    def copy(url, output_file, _pooch):
        shutil.copyfile(src, output_file)
    return copy


@contextmanager
def _quiet_pooch():
    """pooch logs every download at INFO on stderr; slmlab reports once per dataset instead."""
    log = pooch.get_logger()
    level = log.level
    log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        log.setLevel(level)


def _why(exc: Exception) -> str:
    """A short reason for a failed fetch."""
    got = re.search(r"but got (\w+)", str(exc))
    if isinstance(exc, ValueError) and got:
        return f"its SHA-256 is {got.group(1)}, the registry's is different"
    response = getattr(exc, "response", None)
    if response is not None and getattr(response, "status_code", None):
        return f"HTTP {response.status_code}"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return type(exc).__name__


def _remove_empty_dirs(folder: Path) -> None:
    """Remove the empty folders a failed fetch created under (and including) ``folder``."""
    if not folder.is_dir():
        return
    for d in sorted((p for p in folder.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        if not any(d.iterdir()):
            d.rmdir()
    if not any(folder.iterdir()):
        folder.rmdir()


def _fetch_file(store: pooch.Pooch, ds: Dataset, f: DataFile) -> None:
    address, local = file_source(ds, f)
    store.urls[f.path] = address
    try:
        store.fetch(f.path, downloader=_copy_from(local) if local else None, progressbar=False)
    except (OSError, ValueError) as exc:   # requests' errors are OSErrors; a checksum mismatch a ValueError
        _remove_empty_dirs(Path(store.abspath))
        raise SlmlabError(
            f"dataset {ds.name}: file {ds.folder}/{f.path} could not be fetched from {address} ({_why(exc)}); "
            f"fetch it with 'python -m slmlab data fetch {ds.name}' where the network is open, or set "
            f"{ENV_URL} to a server holding the dataset folders (or {ENV_MIRROR} to a local copy)") from None


def fetch(name: str) -> Path:
    """The dataset ``name``'s folder in the cache, every file present and its SHA-256 checked.

    Files missing or altered are fetched (a local mirror first, then ``$SLMLAB_DATA_URL``, then the original
    URL). Raises :class:`SlmlabError` (one line: file, address, remedy) when a file cannot be had, leaving
    no partial file in the cache."""
    ds = dataset(name)
    target = cache_dir() / ds.folder
    store = pooch.create(path=target, base_url="", registry={f.path: f"sha256:{f.sha256}" for f in ds.files},
                         urls={f.path: f.url for f in ds.files}, allow_updates=True)
    with _quiet_pooch():
        for f in ds.files:
            _fetch_file(store, ds, f)
    return target


def available(name: str) -> bool:
    """Whether the dataset ``name`` can be had (cached, or fetched now) without error; an unknown name
    still raises :class:`SlmlabError`. For tests and notebook sections that skip without the data."""
    dataset(name)
    try:
        fetch(name)
    except SlmlabError:
        return False
    return True


def _cached_count(ds: Dataset) -> int:
    """How many of the dataset's files are in the cache with the registry's SHA-256."""
    root = cache_dir() / ds.folder
    return sum((root / f.path).is_file() and pooch.file_hash(str(root / f.path)) == f.sha256 for f in ds.files)


def _source_label(ds: Dataset) -> str:
    mirror = mirror_dir()
    if mirror is not None and (mirror / ds.folder).is_dir():
        return f"mirror {mirror / ds.folder}"
    base = server_url()
    if base:
        return f"{base}/{ds.folder}"
    return f"{ds.repository} at {ds.commit[:12]}"


def status() -> pd.DataFrame:
    """One row per dataset: ``name``, ``files``, ``size_mb``, ``cached`` (``yes``, ``k of n`` or ``no``:
    files present with the right SHA-256), ``source`` (where missing files would come from) and ``title``."""
    rows = []
    for name in names():
        ds = dataset(name)
        k, n = _cached_count(ds), len(ds.files)
        cached = "yes" if k == n else ("no" if k == 0 else f"{k} of {n}")
        rows.append({"name": name, "files": n, "size_mb": round(ds.size_bytes / 1e6, 1), "cached": cached,
                     "source": _source_label(ds), "title": ds.title})
    return pd.DataFrame(rows)
