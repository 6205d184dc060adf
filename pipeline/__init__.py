# The OpenMP runtime reads its wait policy once, when torch loads it: set before any torch import
# (pipeline/infra/threads.py says why and what was measured).
from pipeline.infra.threads import passive_waiting as _passive_waiting

_passive_waiting()
