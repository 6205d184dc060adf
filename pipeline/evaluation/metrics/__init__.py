"""What is measured: the one metric specification (``spec``), calibration (reliability, ECE), the
results tables and their writer, and the labels people read for methods and comparisons."""
