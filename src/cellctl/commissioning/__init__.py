"""Commissioning: calibration, teaching and verification run by the service as jobs, through the ports.

- :mod:`~cellctl.commissioning.plans`: where each procedure moves the robot (reach-checked, costed);
- :mod:`~cellctl.commissioning.prompts`: what the engineer is asked, and the answers;
- :mod:`~cellctl.commissioning.context`: what a procedure works with (ports, prompts, its dataset);
- :mod:`~cellctl.commissioning.procedures`: the procedures themselves (camera, hand-eye, laser,
  teaching, nine-point), :mod:`~cellctl.commissioning.verify` the drift check;
- :mod:`~cellctl.commissioning.registry`: the procedures a job may run, their options;
- :mod:`~cellctl.commissioning.jobs`: one job at a time in Stopped or Idle, cancel, records;
- :mod:`~cellctl.commissioning.schedule`: when a drift check is due;
- :mod:`~cellctl.commissioning.cli` and :mod:`~cellctl.commissioning.terminal`: ``cellctl calibrate``
  (its options: :mod:`~cellctl.commissioning.cli_parser`).
"""
