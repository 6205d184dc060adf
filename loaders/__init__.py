import pipeline.infra.decoder_limits  # noqa: F401,E402  OpenCV's decoder limits, set before any cv2 import
