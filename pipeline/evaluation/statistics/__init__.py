"""The statistics engine: one hierarchical resampler (``resampler``), verdict records and the
outcome rule (``records``), pooled values, paired differences and records of every population
(``engine``), the pooled ECE on the engine's draws (``pooled_calibration``) and Holm over the primary family
(``multiplicity``)."""
