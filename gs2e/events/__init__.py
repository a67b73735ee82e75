"""gs2e.events stage."""
