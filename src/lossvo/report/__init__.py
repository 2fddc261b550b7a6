"""The sweep report: ``python -m lossvo.report SWEEP_DIR`` turns a Hydra sweep's job folders into the
study's tables, figures and claims (mean ± sample std over seeds; per architecture where the sweep varies
it). See docs/report.md.
"""
