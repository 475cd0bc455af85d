"""Benchmarks: the stack's cost measured side by side against the same physics alone.

:mod:`hil.bench.run` is ``elegant-stepping bench`` (ratios in one run, JSON out);
:mod:`hil.bench.socketcan` the HIL figures on a real vcan0 beside their floor.

May import: ``controller``, ``firmware_sim``, ``protocol``, and the harness's lockstep, session,
experiments and uml packages.
"""
