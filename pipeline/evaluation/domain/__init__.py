"""The test domain: residuals of the labelled AVD crops against the class models, the cross-fitted
test-domain variance of the calibrated likelihood, and the domain-fit summary."""
