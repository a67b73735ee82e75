"""The paper's downstream benchmark on a gs2e dataset, against its own ground
truth (the sharp frames). Its tasks, registered in :mod:`gs2e.bench.tasks`:
event-based deblurring (:mod:`gs2e.bench.deblur_task`, EDI in
:mod:`gs2e.bench.deblur`), video reconstruction from events
(:mod:`gs2e.bench.video_task`, :mod:`gs2e.bench.video`) and event-based 3D
reconstruction, a 3DGS model trained from the trajectory alone
(:mod:`gs2e.bench.recon3d`, the paper's Table 1); what they read and how they
score (:mod:`gs2e.bench.dataset`), the built-in baselines and a user's own
method (:mod:`gs2e.bench.methods`), the I/O edge (:mod:`gs2e.bench.run`) and
the dataset table (:mod:`gs2e.bench.summary`)."""
