"""The main report of a run (``page``): bottom line, verdict, track, calibration sections, figures."""
