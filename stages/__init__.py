"""The pipeline's stages, one module each (``data``, ``classifier``, ``features``, ``models``,
``evaluate``, ``report``, ``simulate``), each with ``run(ctx)``. The framework that runs them is in
``stages.framework`` and the commands (CLI, study, compare) in ``stages.commands``. A stage
imports the framework's public names only, never another stage."""
import pipeline.infra.decoder_limits  # noqa: F401,E402  OpenCV's decoder limits, set before any cv2 import
