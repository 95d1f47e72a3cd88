"""slmlab's version: one place, read by the package, its files' ``source`` lines and the build."""

__version__ = "0.1.0"
