"""Replay a finished run: a headless side-by-side video and a 3D recording (rerun) of every method.

A run directory records the concrete scenario it simulated (``replay.toml``, marked in
``summary.json`` under ``replay``); the arm is redrawn from each method's per-step joint angles
and the person from the scenario's keyframes at the same instant. Nothing is simulated again.

Modules, one job each: :mod:`~compare.replay.run_data` (find and load a run),
:mod:`~compare.replay.scene` (the MuJoCo state at an instant, geometry),
:mod:`~compare.replay.overlay` (what a video panel shows), :mod:`~compare.replay.panels`
(draw the frames), :mod:`~compare.replay.video` (encode them), :mod:`~compare.replay.depth`
(depth point clouds), :mod:`~compare.replay.recording` (the ``.rrd`` file, with
:mod:`~compare.replay.rerun_shapes` and :mod:`~compare.replay.rerun_series`).
"""
