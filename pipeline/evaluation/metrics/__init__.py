"""What is measured: the one metric specification (``spec``), calibration (reliability, ECE), the
results tables and their writer, the labels people read for methods and comparisons, and the
paper's claims about them with its own numbers (``paper``: the main report's scorecard)."""
