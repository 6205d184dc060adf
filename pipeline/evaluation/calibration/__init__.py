"""The calibration suite: populations with a known answer in every design the configs use
(``simulate``) and what the engine's intervals cover on them (``suite``; ``make calibrate`` writes
docs/calibration.md, ``tools/calibrate.py``)."""
