"""gs2e.metrics stage."""
