"""The statistics: hierarchical bootstrap CIs over targets and tracks, paired differences, robust
estimates, verdicts, pooled calibration and the pooling of classifier seeds."""
