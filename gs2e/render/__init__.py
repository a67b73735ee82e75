"""gs2e.render stage."""
