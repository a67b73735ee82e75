"""gs2e.trajectory stage."""
