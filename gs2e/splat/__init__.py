"""gs2e.splat stage."""
