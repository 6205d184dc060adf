"""The simulate stage's page: the section 5.3 scenarios, the claims and the regime sweep."""
