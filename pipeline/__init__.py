# OpenCV reads its decoder limits once, when it is loaded: set them before any module here or in
# the floors above imports cv2 (pipeline/infra/decoder_limits.py).
from pipeline.infra import decoder_limits as _decoder_limits

_decoder_limits.install()
