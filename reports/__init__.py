"""HTML and PNG reports, one sub-room per page (``main``, ``simulate``, ``compare``, ``study``) and
``shared`` for what every page uses (HTML builder, number formatter, figure helpers, run artifacts).
Pages import ``shared``, never each other."""
import pipeline.infra.decoder_limits  # noqa: F401,E402  OpenCV's decoder limits, set before any cv2 import
