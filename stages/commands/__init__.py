"""The commands: ``viewfuse`` (cli), ``viewfuse study`` and ``viewfuse compare``."""
