# Two native runtimes read their settings once, when they load, so both are set here before any
# module in this package or the floors above imports torch or cv2:
# - the OpenMP wait policy (pipeline/infra/threads.py says why and what was measured);
# - OpenCV's decoder limits (pipeline/infra/decoder_limits.py).
from pipeline.infra import decoder_limits as _decoder_limits
from pipeline.infra.threads import passive_waiting as _passive_waiting

_passive_waiting()
_decoder_limits.install()
