"""The seed study's page."""
