"""The population grid: candidate sets, tracks and their localization settings, the experiments of
one cell, the reduction of cells to results, the population's summary and calibration blocks, the
showcase tracks."""
