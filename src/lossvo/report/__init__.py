"""The sweep report: ``python -m lossvo.report SWEEP_DIR`` turns a Hydra sweep's job folders into the
study's tables, figures and claims.

A Hydra multirun (``python -m lossvo.train -m loss=euler,quat,chordal [seed=0,1,2]``) leaves one job folder
per run, ``SWEEP_DIR/<num>_<overrides>/``, with ``.hydra/{config,overrides}.yaml``, ``status.json``,
``metrics.csv``, ``results.json`` and ``trajectories/NN.txt``. The report writes into ``--out`` (default
``SWEEP_DIR/report/``) ``report.md``, ``tables/`` (CSV and LaTeX) and ``figures/`` (PNG), and caches the
baselines under ``cache/``. It reads the job folders (results.json only through
:class:`lossvo.evaluation.results.Results`), the ground-truth pose files that results.json names, and, for
the baselines, the recorded dataset's frames (PNGs), calib.txt and pose files; it never builds a
datamodule: the evaluated dataset, the training split and the unseen-motion sequences come from each
job's results.json.

Configurations are named by the overrides that differ between jobs (``loss=euler`` vs ``loss=quat``, or
``loss.k=50`` vs ``loss.k=100``); ``seed`` is the replicate axis: with several seeds a cell is the mean ±
sample standard deviation (ddof = 1) over seeds. Where the configurations span several architectures (the
``model`` config group's choice), the tables, curves, pairs and claims are given per architecture.

Modules, by concern:

- :mod:`~lossvo.report.jobs`: the sweep folder and its job folders (Job, status, metrics.csv curves,
  results.json, trajectories and ground truth);
- :mod:`~lossvo.report.configurations`: jobs grouped into configurations, rotation weights, selection;
- :mod:`~lossvo.table_render`: the one table renderer (markdown, CSV, LaTeX) of every section's rows;
- :mod:`~lossvo.report.tables`: the per-sequence tables (cells, mean row, bold minima) and their rows;
- :mod:`~lossvo.report.statistics`: the paired test, the significance level, the verdict rule,
  convergence epochs, the architecture x loss interaction test;
- :mod:`~lossvo.report.comparison`, :mod:`~lossvo.report.convergence`, :mod:`~lossvo.report.claims`:
  the pairwise comparison, the convergence epochs and the study's claims;
- :mod:`~lossvo.report.architectures`: where a sweep varies the architecture (``model=deepvo_small,flowvo``),
  each architecture's ranking of the losses and the interaction test;
- :mod:`~lossvo.report.against_baselines`: the baselines (:mod:`lossvo.evaluation.baselines`) as
  columns and a section, each job against them;
- :mod:`~lossvo.report.figures`: curves, trajectories, APE bars;
- :mod:`~lossvo.report.document`: report.md and the files (:func:`~lossvo.report.document.make_report`);
- :mod:`~lossvo.report.cli`: the command line.
"""
