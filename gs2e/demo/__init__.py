"""gs2e.demo stage."""
