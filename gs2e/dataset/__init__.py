"""A dataset of many scenes: quality gates per scene, each scene's status after a
run (passed, failed with a one-line reason) and the dataset's card.

- :mod:`gs2e.dataset.gates`: the values a gate reads and the verdict (pure).
- :mod:`gs2e.dataset.status`: which scenes a run finished and why the others failed.
- :mod:`gs2e.dataset.card`: the datasheet (sources and terms read from the inputs).
- :mod:`gs2e.dataset.cli`: ``gs2e gate``, ``gs2e dataset-status``, ``gs2e datasheet``.
"""
