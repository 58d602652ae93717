"""Sweeps: many ordinary training runs (configurations x seeds) on Ray Tune, and their tables and reports.

A sweep file (``sweeps/*.toml``, read by ``spec.load_sweep``) names a base preset with ``--set``
overrides, the parameters that vary, the seeds, the metric and how trials are scheduled.
``runner`` starts the trials on a local Ray instance or a cluster; each trial (``trial``) builds
its ``TrainConfig`` and calls the ordinary ``Trainer.train``, reporting every iteration and each
saved checkpoint to Tune. ``results`` turns the trials' reports into one tidy table and
``report`` reads that table. The trainer knows nothing of Tune; only ``trial`` and ``runner``
import Ray.
"""
