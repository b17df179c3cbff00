"""The toolkit's version, written into every shard and model file (pyproject.toml says the same)."""

__version__ = "0.1.0"
