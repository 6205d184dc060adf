"""The stage framework: the registry (stages, their sections and code), the runner (staleness,
locks, manifests), the run folder, and where a run reads its datasets."""
