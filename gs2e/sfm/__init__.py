"""gs2e.sfm stage."""
