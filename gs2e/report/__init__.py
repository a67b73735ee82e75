"""HTML report of a results tree: speed against error, stage costs, event
statistics against a real recording, thumbnails and event previews.

:mod:`gs2e.report.plots` holds pure functions (arrays/tables -> figures,
images, PNG bytes), :mod:`gs2e.report.html` the self-contained HTML assembler,
:mod:`gs2e.report.io` the reading of a results tree and
:mod:`gs2e.report.build` puts them together (``gs2e report``).
"""
