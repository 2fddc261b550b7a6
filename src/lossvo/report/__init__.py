"""The sweep report: ``python -m lossvo.report SWEEP_DIR`` turns a Hydra sweep's job folders into the
study's tables, figures and claims (``report.md``, ``tables/``, ``figures/`` under ``--out``). It reads
job folders and the recorded datasets, never a datamodule. Configurations are named by the overrides that
differ between jobs; ``seed`` is the replicate axis (a cell is mean ± sample std over seeds); where a sweep
varies the architecture, everything is given per architecture. See docs/report.md.
"""
