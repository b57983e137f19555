"""The ``python -m capture_bench sweep`` job: every algorithm x scenario x training seed trained
as a Ray task. The command (`command`: options checked before work, the plan, ``sweep.json``),
the driver's side (`driver`: tasks sent, run directories installed as they come back) and one run
on its node (`task`)."""
