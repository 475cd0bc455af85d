"""Benchmarks: the stack's cost measured side by side against the same physics alone.

:mod:`hil.bench.run` is ``elegant-stepping bench`` (ratios in one run, JSON out), against the
physics floor of :mod:`hil.bench.physics_floor`; :mod:`hil.bench.profile` is ``bench --profile``
(where the time goes, per layer); :mod:`hil.bench.socketcan` the HIL figures on a real vcan0
beside their floor; :mod:`hil.bench.floor` the platform's floor beside a real-time session.

May import: ``controller``, ``firmware_sim``, ``protocol``, and the harness's lockstep, session,
experiments and uml packages.
"""
