"""The harness that joins the controller and the simulated leg.

In-process lockstep over python-can's ``virtual`` bus (:mod:`hil.lockstep.harness`, for tests and fast
experiments); the learning experiment (:mod:`hil.experiments.learn`), its baselines (:mod:`hil.experiments.methods`,
:mod:`hil.experiments.oracle`), sweeps on a process pool or Dask (:mod:`hil.experiments.sweep`, :mod:`hil.analysis.report`),
analysis and figures (:mod:`hil.analysis.metrics`, :mod:`hil.analysis.figures`, :mod:`hil.analysis.animation`);
hardware-in-the-loop over SocketCAN, inside User-Mode Linux where the kernel has no CAN
(:mod:`hil.session.run`, :mod:`hil.uml.runner`, :mod:`hil.analysis.replay`); the controller daemon and its periodic
weight saves (:mod:`controller.daemon.run`, :mod:`controller.daemon.autosave`), its systemd notifications
(:mod:`controller.daemon.sdnotify`, :mod:`controller.daemon.notify`) and the deployment dry run that plays systemd
(:mod:`hil.dryrun.run`, :mod:`hil.dryrun.notify_listener`, :mod:`hil.dryrun.unitfile`); the bring-up command
(:mod:`controller.cli.bringup`); the fault matrix (:mod:`hil.faults.matrix`); benchmarks (:mod:`hil.bench.run`,
:mod:`hil.bench.socketcan`); fault injection on the bus (:mod:`hil.faults.model`), in HIL sessions (the
man-in-the-middle node :mod:`hil.faults.mitm`, kill -9 and silence events :mod:`hil.faults.session`, the
leg's heartbeats :mod:`hil.session.legwatch`) and during weight saves (:mod:`hil.faults.killsave`) and the
``elegant-stepping`` command line (:mod:`hil.cli.main`).

May import everything: ``controller``, ``firmware_sim``, ``protocol``, ``urdf``. It is the only
package that sees both sides of the bus.
"""
