"""``ConfigError``, outside the config package so that the modules the config package imports
(the dataset sources' registry, ``pipeline/infra/datasets.py``) raise it without importing the
package back (``pipeline.infra.config`` re-exports it)."""


class ConfigError(ValueError):
    """A config file is malformed; the message names the file and the key."""
