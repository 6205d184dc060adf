"""The built-in dataset sources (``pipeline.infra.datasets``): one module per value of
``data.source``; a new module here registers without editing any list."""
